"""Step speed of the full Baudet model against a bare spring lattice, measured side by side.

    python benchmarks/step_speed.py [--shape 10 10 10] [--repeats 200]

Scene and measurements: ``sim_core.studies.bench`` (a block of 0.1 m cubes sagging under a reduced
gravity). Reports medians of repeated steps (ms), full model and bare lattice (same springs, no
corrections or volume forces) interleaved call by call, CG/BiCGSTAB iterations, a static shear solve
(ms), the ratios to the bare lattice (explicit; implicit at a fixed 15 iterations, converged to the
same tolerance, and the full model's converged step against the bare fixed-15 CG step), and the
memory-bandwidth floor (compulsory bytes per step / numpy-copy bandwidth measured in the same run),
and the implicit step with ImplicitEuler's factorised preconditioner against Jacobi, on this block
(``implicit_step_factorised_ms``, ``implicit_step_auto_ms``) and on TumorPositioning's stiff 5 cm
block at 4^3 / dt 20 ms and 7^3 / dt 40 ms (``stiff_4_*``, ``stiff_7_*``).
Writes benchmarks/results/step_speed.json. Timing is never asserted in tests: machines are shared.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from training.common import write_json  # noqa: E402
from sim_core.studies.bench import measure  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", type=int, nargs=3, default=[10, 10, 10])
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "step_speed.json"))
    args = parser.parse_args(argv)
    results = measure(args.shape, args.repeats)
    write_json(args.out, results)
    width = max(len(k) for k in results)
    for key, value in results.items():
        if key != "machine":
            print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
