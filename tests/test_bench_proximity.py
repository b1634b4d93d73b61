"""``depthguard bench proximity --quick --json``: the JSON contract (timings, peer, ratio, target)."""

import json

from depthguard.cli import main


def test_bench_proximity_quick_json(capsys):
    assert main(["bench", "proximity", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    res = out["results_us"]
    for k in ("nsb_cycle", "pinv_cycle", "nsb_cycle_numpy", "safety_level_update"):
        assert res[k]["us_median"] > 0 and res[k]["us_p99"] >= res[k]["us_median"]
    assert out["parameters"]["dof"] == 8 and out["parameters"]["sensors"] == 10
    assert out["ratios"]["nsb_over_pinv_median"] > 0
    assert out["target"]["nsb_cycle_p99_us"] == 100.0 and "load_average_1min" in out["machine"]
