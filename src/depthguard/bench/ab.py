"""A/B timing of the distance kernels: this tree against an older git revision, in one process.

``python -m depthguard.bench.ab --old REV [--quick]`` extracts ``src/depthguard`` of ``REV`` (``git archive``)
into a temporary package ``depthguard_ab_old``, imports both versions side by side and times the same
queries on the same frames, alternating old and new in rounds so that the load of a shared machine
affects both alike. Prints JSON: per case the median time of each version (median over the rounds of the
per-round medians), ``new_over_old`` and whether the answers agree (to 1e-9 m; the refactor may change
rounding through fast-math re-association). Used for the refactor's "no slowdown" check (BENCHMARKS.md).

Caution (measured 2026-12-02): with both versions' kernels loaded in one process, one of them ran 2x
slower than it did alone in a process, the same code either way, so a slowdown found here must be
confirmed in separate processes (BENCHMARKS.md, "ral-shadow at 640x480").
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from depthguard.bench.timing import machine_info, reference_speed, time_calls

__all__ = ["load_old", "run_ab"]


def load_old(rev: str):
    """Import ``src/depthguard`` of git revision ``rev`` as the package ``depthguard_ab_old``."""
    root = Path(__file__).resolve().parents[3]
    tmp = Path(tempfile.mkdtemp(prefix="depthguard_ab_"))
    tar = subprocess.run(["git", "-C", str(root), "archive", rev, "src/depthguard"], check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(tmp)], input=tar.stdout, check=True)
    pkg = tmp / "depthguard_ab_old"
    (tmp / "src" / "depthguard").rename(pkg)
    # only the distance modules are taken from the old revision; cameras, scenes etc. stay shared
    pat = re.compile(r"\bdepthguard(?=\.(depthspace|depthgrid|kernels)\b)")
    for f in pkg.rglob("*.py"):
        text = f.read_text()
        lines = [
            pat.sub("depthguard_ab_old", ln) if re.match(r"\s*(from|import)\s", ln) else ln for ln in text.splitlines()
        ]
        f.write_text("\n".join(lines) + "\n")
    (pkg / "__init__.py").write_text("")
    sys.path.insert(0, str(tmp))

    return pkg


def _cases(quick: bool):
    """(name, setup(pkg) -> callable returning distances) for both versions."""
    from depthguard.bench.scenes import arm_chain_points, bench_cameras, noisy_depth, person_scene, shadow_frames

    cams = bench_cameras()
    scene = person_scene()
    depths = [noisy_depth(c, scene, seed=1 + i) for i, c in enumerate(cams)]
    _, centres, radii = arm_chain_points()
    sh = shadow_frames()

    def depthspace(mode):
        def make(pkg):
            ds = __import__(f"{pkg}.depthspace", fromlist=["x"])
            frame = ds.prepare_frame(cams[0], depths[0])
            return lambda: ds.query_distances(frame, centres, radii, rho=0.4, mode=mode).distance

        return make

    def grid(mode, frames):
        def make(pkg):
            dg = __import__(f"{pkg}.depthgrid", fromlist=["x"])
            f = dg.DepthGridFusion(frames["cameras"], dd=0.01, workspace=frames["workspace"])
            f.update(frames["depths"], frames["masks"])
            c, r = frames["centres"], frames["radii"]
            return lambda: f.query(c, r, rho=0.4, mode=mode).distance

        return make

    bench = {"cameras": cams, "workspace": (-1.5, 1.5, -1.5, 1.5, -0.5, 1.5), "depths": depths, "masks": None}
    bench.update(centres=centres, radii=radii)
    cases = [
        ("depthspace-1cam-min", depthspace("min")),
        ("depthspace-1cam-all", depthspace("all")),
        ("depthgrid-2cam-all", grid("all", bench)),
        ("depthgrid-2cam-min", grid("min", bench)),
        ("depthgrid-2cam-shadow-hybrid", grid("hybrid", sh)),
    ]
    return cases


def run_ab(old_rev: str, quick: bool = False, rounds: int | None = None) -> dict:
    """Time every case with the old and the new code; returns the JSON-able result."""
    load_old(old_rev)
    rounds = rounds or (3 if quick else 9)
    repeat = 20 if quick else 60
    out = {"benchmark": "ab", "old": old_rev, "machine": machine_info(), "reference": reference_speed(), "cases": []}
    for name, make in _cases(quick):
        fns = {"old": make("depthguard_ab_old"), "new": make("depthguard")}
        a, b = fns["old"](), fns["new"]()
        agree = bool(np.array_equal(np.isfinite(a), np.isfinite(b)) and np.allclose(a, b, atol=1e-9, equal_nan=True))
        med = {"old": [], "new": []}
        for _ in range(rounds):
            for k in ("old", "new"):
                med[k].append(time_calls(fns[k], repeat)["us_median"])
        o, n = float(np.median(med["old"])), float(np.median(med["new"]))
        out["cases"].append({"name": name, "old_us": o, "new_us": n, "new_over_old": n / o, "answers_agree": agree})
    return out


if __name__ == "__main__":  # pragma: no cover
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, help="git revision of the old code")
    ap.add_argument("--quick", action="store_true")
    ns = ap.parse_args()
    print(json.dumps(run_ab(ns.old, ns.quick), indent=2))
