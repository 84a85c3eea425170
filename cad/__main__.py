"""``python -m cad build [--out DIR] [--svg-dir DIR] [MODEL ...]`` and ``python -m cad list``.

``build`` writes each part of each model as STEP (machining, CAD) and STL (printing) into
``--out``, plus an SVG drawing of the model; ``--svg-dir`` also puts the drawing there
(``make cad`` uses ``docs/cad``). Bad input ends with one line on stderr and a non-zero exit:
2 for a bad command line, 1 when a file cannot be written or a model cannot be built.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

DEFAULT_OUT = Path("var/cad")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        # One line, not argparse's usage block: scripts and make show it as it is.
        self.exit(2, f"cad: error: {message}\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m cad", description="Build the parametric CAD models.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    build = commands.add_parser("build", help="write STEP, STL and SVG files")
    build.add_argument("--out", type=Path, default=DEFAULT_OUT, help="default: var/cad")
    build.add_argument("--svg-dir", type=Path, default=None, help="also write the SVGs here")
    build.add_argument("models", nargs="*", metavar="MODEL", help="default: every model")
    commands.add_parser("list", help="name every model")
    return parser


class _Unwritable(Exception):
    pass


def _writable(directory: Path) -> None:
    """Create ``directory`` and prove a file can be written there, before any slow work."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        reason = exc.strerror or exc.__class__.__name__
        raise _Unwritable(f"cannot write to {directory}: {reason}") from None


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    # cadquery takes a second or two to import: not for --help or a bad command line.
    from cad.models import MODELS

    if args.command == "list":
        for model in MODELS.values():
            print(f"{model.name:16} {model.summary}")
        return 0

    unknown = [name for name in args.models if name not in MODELS]
    if unknown:
        print(
            f"cad: error: unknown model {unknown[0]!r} (choose from {', '.join(MODELS)})",
            file=sys.stderr,
        )
        return 2
    names = list(dict.fromkeys(args.models)) or list(MODELS)
    try:
        for directory in (args.out, args.svg_dir):
            if directory is not None:
                _writable(directory)
    except _Unwritable as exc:
        print(f"cad: error: {exc}", file=sys.stderr)
        return 1

    from cad.export import summarise, write_step, write_stl, write_svg

    for name in names:
        try:
            built = MODELS[name].build()
        except ValueError as exc:
            print(f"cad: error: {name}: {exc}", file=sys.stderr)
            return 1
        for part, solid in built.parts().items():
            stem = args.out / f"{name}-{part}"
            write_step(solid, stem.with_suffix(".step"))
            write_stl(solid, stem.with_suffix(".stl"))
            s = summarise(part, solid)
            x, y, z = s.size_mm
            print(
                f"{name + '/' + part:22} {x:6.1f} x {y:6.1f} x {z:5.1f} mm"
                f"  {s.volume_mm3:9.0f} mm3  {stem}.step {stem}.stl"
            )
        drawing = write_svg(built.exploded(), args.out / f"{name}.svg")
        written = [drawing]
        if args.svg_dir is not None:
            copy = args.svg_dir / drawing.name
            copy.write_bytes(drawing.read_bytes())
            written.append(copy)
        print(f"{name + ' drawing':22} {' '.join(str(w) for w in written)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
