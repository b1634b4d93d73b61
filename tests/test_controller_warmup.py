"""The controller node's warm-up: it must drive the moving path (status OK), not only the stopped one, so
that no kernel is first used inside the node's real-time loop."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_warm_up_reaches_the_moving_path():
    from depthguard.io.cellfile import read_cell
    from depthguard.nodes.controller import warm_up
    from depthguard.runner.chain import _controller_config, cell_control_points, load_cell_robot

    cell = read_cell(ROOT / "examples/cells/sim-hexagon.toml")
    model = load_cell_robot(cell)
    points, config = cell_control_points(cell, model), _controller_config(cell)
    assert warm_up(points, config, model) == "OK"
    assert warm_up(points, config, model, cycles=0) == "-"
