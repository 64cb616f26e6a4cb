"""benchmarks/report.py reads the figures the benchmarks print and writes the performance page:
each figure with its benchmark and ratio, the provenance in a generated block, a failed
benchmark named on the page and in the exit code. Times are never asserted; the outputs below
are what the benchmarks print, in their format, with made-up figures."""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import report  # noqa: E402

OUTPUTS = {
    "loop": "speedup_vs_python_control=2000 max_abs_diff_m=6e-14 product_s=0.04\n",
    "exit": ("exit collected: median 0.80 s (range 0.7 to 0.9 s)\n"
             "exit ended    : median 0.04 s (range 0.03 to 0.05 s)\n"),
    "diagnose": "samples: 400000  diagnose wall time: 2.1 s, CPU 2.0 s  (target <= 5 s)\n",
    "iteration_floor": (
        "n_l = 16: product  12.00 ms, reference  15.00 ms, restructured  10.00 ms; ...\n"
        "n_l =  8: product   6.00 ms, reference   7.50 ms, restructured   5.00 ms; ...\n"
        "the table's 12,268 iterations (6,134 at n_l = 16, 6,134 at n_l = 8): 110.4 s at the "
        "product rate, 138.0 s at the reference rate, 92.0 s at the restructured rate (the "
        "fits' iterations alone)\n"),
    "table": ("total_cpu_s=140.0 fits_s=100.0 not_fitting_s=40.0 iterations=12268\n"
              "floor_s=100.0 bar_ratio=1.400\n"),
}


def _kept(tmp_path: Path, broken: str | None = None) -> Path:
    keep = tmp_path / "keep"
    keep.mkdir()
    jobs = {}
    for name, out in OUTPUTS.items():
        (keep / f"{name}.out").write_text("nothing to read\n" if name == broken else out)
        (keep / f"{name}.err").write_text("")
        jobs[name] = {"args": [f"benchmarks/bench_{name}.py"], "code": 0, "wall_s": 1.0,
                      "cpu_s": 1.0, "quick": False, "load": [0.5, 0.6], "commit": "abc1234",
                      "finished": "today"}
    (keep / "meta.json").write_text(json.dumps({"jobs": jobs}))
    return keep


def test_the_page_has_each_figure_with_its_benchmark_and_ratio(tmp_path, capsys):
    page = tmp_path / "performance.md"
    assert report.main(["--from", str(_kept(tmp_path)), "--out", str(page)]) == 0
    text = page.read_text(encoding="utf-8")
    rows = {line.split(" | ")[0].lstrip("| "): line for line in text.splitlines()
            if line.startswith("| ") and "`bench_" in line}
    assert "2,000× faster" in rows["closed loop, 400,000 samples (default plant, PID, dither)"]
    assert "0.1 % of it" in rows["closed loop, one 10 kHz sample"]  # 100 ns of 100 µs
    assert "0.40×" in rows["`diagnose` on a 400,000-sample record (every candidate)"]
    assert "20× faster" in rows["a finished command's exit (torch, control, scipy, numba loaded)"]
    assert "1.20×" in rows["one LM iteration of a paper's-cost fit, n_l = 16"]
    assert "1.20×" in rows["the paper table's 12,268 LM iterations (run)"]  # 110.4 / 92.0
    assert "71 % fits" in rows["the paper table on one core"]
    assert "1.40×" in rows["the paper table on one core, against its floor"]
    assert "<!-- provenance:" in text and "abc1234" in text
    assert all(len(line) <= 100 for line in text.splitlines() if not line.startswith("|"))


def test_a_benchmark_it_cannot_read_is_named_and_fails_the_run(tmp_path, capsys):
    page = tmp_path / "performance.md"
    assert report.main(["--from", str(_kept(tmp_path, broken="diagnose")), "--out",
                        str(page)]) == 1
    assert "**Not read**" in page.read_text(encoding="utf-8")
    assert "diagnose" in capsys.readouterr().out
