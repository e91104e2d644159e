"""``tissue-sim``: the validation experiments from the shell.

    tissue-sim elongation --shape 10 10 10 --spacing 0.1 --young-modulus 1e4 --poisson-ratio 0.3 --strain 0.01 --json
    tissue-sim shear --angle-deg 5 --compare fem-linear --json
    tissue-sim flexion --shape 10 5 4 --density 1500 --gravity 0.04 --save bent.vtu
    tissue-sim bench --shape 10 10 10 --json
    tissue-sim --version

Bad arguments end with exit code 2 and a one-line message.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from .. import __version__
from ..geometry.mesh import HexMesh
from . import experiments
from .bench import measure

#: --save extensions: the meshio formats that keep the hexahedra and the displacement point data
#: with the base dependencies (.msh is written as binary Gmsh 4.1, see HexMesh.write; .xdmf and the
#: other HDF5 formats need h5py).
SAVE_FORMATS = (".vtu", ".vtk", ".msh")


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit code 2, no usage dump
        sys.stderr.write(f"tissue-sim: error: {message}\n")
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tissue-sim", description="Baudet mass-spring validation experiments (SI units).")
    parser.add_argument("--version", action="version", version=f"tissue-sim {__version__}")
    commands = parser.add_subparsers(dest="experiment", required=True, parser_class=_Parser)
    for name, help_text in (("elongation", "uniaxial pull along x"), ("shear", "simple shear of the top face"),
                            ("flexion", "cantilever under gravity")):
        sub = commands.add_parser(name, help=help_text)
        default_shape = [10, 5, 4] if name == "flexion" else [10, 10, 10]
        sub.add_argument("--shape", type=int, nargs=3, default=default_shape, metavar=("NX", "NY", "NZ"))
        sub.add_argument("--spacing", type=float, default=0.1, help="element size, m")
        sub.add_argument("--young-modulus", type=float, default=1e4, help="Pa")
        sub.add_argument("--poisson-ratio", type=float, default=0.3)
        sub.add_argument("--density", type=float, default=1500.0, help="kg/m^3")
        sub.add_argument("--model", default="baudet", choices=experiments.MODELS)
        sub.add_argument("--hourglass-control", type=float, default=None,
                         help="hourglass control alpha (mass-spring models)")
        sub.add_argument("--compare", choices=experiments.FEM_MODELS, default=None,
                         help="also run this reference and report %%e_dm, %%e_max")
        sub.add_argument("--json", action="store_true", help="one JSON object on stdout")
        sub.add_argument("--save", metavar="FILE.vtu",
                         help=f"write the deformed mesh (format by extension: {', '.join(SAVE_FORMATS)})")
        if name == "elongation":
            group = sub.add_mutually_exclusive_group()
            group.add_argument("--strain", type=float, help="imposed engineering strain")
            group.add_argument("--force", type=float, help="imposed total force, N")
        elif name == "shear":
            sub.add_argument("--angle-deg", type=float, default=5.0)
        else:
            sub.add_argument("--gravity", type=float, default=0.04, help="m/s^2, acts along -y")
    bench = commands.add_parser("bench", help="step speed of the full model and of a bare spring lattice")
    bench.add_argument("--shape", type=int, nargs=3, default=[10, 10, 10], metavar=("NX", "NY", "NZ"))
    bench.add_argument("--repeats", type=int, default=100)
    bench.add_argument("--json", action="store_true", help="one JSON object on stdout")
    return parser


def _check_save(path: str) -> None:
    """Refuse a --save file before computing: an unsupported extension or a missing folder."""
    target = Path(path)
    if target.suffix not in SAVE_FORMATS:
        raise ValueError(f"--save {path}: unsupported mesh format {target.suffix or '(no extension)'!r}; "
                         f"use one of {', '.join(SAVE_FORMATS)}")
    if not target.parent.is_dir():
        raise ValueError(f"--save {path}: folder {target.parent} does not exist")


def _bench(args) -> int:
    if min(args.shape) < 1 or args.repeats < 1:
        sys.stderr.write("tissue-sim: error: --shape needs positive integers and --repeats >= 1\n")
        return 2
    results = measure(args.shape, args.repeats)
    if args.json:
        print(json.dumps(results, default=_jsonable))
    else:
        for key, value in results.items():
            print(f"{key:>45}: {value}")
    return 0


def _run(args, model):
    common = dict(shape=args.shape, spacing=args.spacing, young_modulus=args.young_modulus,
                  poisson_ratio=args.poisson_ratio, model=model)
    options = {}
    if args.hourglass_control is not None and model not in experiments.FEM_MODELS:
        options["hourglass_control"] = args.hourglass_control
    if args.experiment == "elongation":
        strain = args.strain if args.strain is not None or args.force is not None else 0.01
        return experiments.elongation(**common, strain=strain, force=args.force, density=args.density, **options)
    if args.experiment == "shear":
        return experiments.shear(**common, angle_deg=args.angle_deg, density=args.density, **options)
    return experiments.flexion(**common, density=args.density, gravity=args.gravity, **options)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if args.experiment == "bench":
        return _bench(args)
    try:
        if args.save:
            _check_save(args.save)
        result = _run(args, args.model)
        summary = result.summary()
        if args.compare:
            reference = _run(args, args.compare)
            e_dm, e_max = experiments.position_errors(result, reference)
            summary["compare"] = {"model": args.compare, "e_dm_percent": e_dm, "e_max_percent": e_max,
                                  "reference": reference.summary()}
        if args.save:
            mesh = HexMesh.block(args.shape, args.spacing)
            mesh.write(args.save, positions=result.positions,
                       point_data={"displacement": result.positions - result.rest_positions})
            summary["saved"] = args.save
    except (ValueError, OSError) as error:
        sys.stderr.write(f"tissue-sim: error: {error}\n")
        return 2
    if args.json:
        print(json.dumps(summary, default=_jsonable))
    else:
        for key, value in summary.items():
            print(f"{key:>20}: {value}")
    return 0 if result.converged else 1


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value)}")


if __name__ == "__main__":
    raise SystemExit(main())
