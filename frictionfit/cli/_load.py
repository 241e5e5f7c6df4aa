"""Reading recordings for a command: skipped files named on stderr, counts said."""

from __future__ import annotations

import os
import warnings
from collections import Counter
from pathlib import Path

import typer

STRICT_HELP = ("Stop at the first recording that cannot be used (default: skip it, naming it "
               "and why).")
#: The whole-measurement fits' laws, as the commands that fit them explain them.
WHOLE_LAWS_HELP = ("auto (by BIC: no static peak, a static peak, or a static peak with viscous "
                   "damping), no_peak2, relaxation, relaxation2 or rich.")


def fail(message: str, code: int = 1):
    """Print ``error: message`` on stderr and leave with ``code``."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def load_recordings(spec: str, strict: bool = False) -> list:
    """The recordings of ``KIND:PATH``; each one left out is named with its reason on stderr,
    then how many were used (``strict``: the first bad one stops the command)."""
    from frictionfit.datasets import load_dataset
    from frictionfit.errors import FrictionfitError
    from frictionfit.recording import DatasetWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        try:
            recordings = load_dataset(spec, strict=strict)
        except FrictionfitError as exc:
            fail(str(exc))
    skipped = [w for w in caught if issubclass(w.category, DatasetWarning)]
    for w in caught:
        if w in skipped:
            typer.echo(str(w.message), err=True)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if not recordings:
        fail(f"dataset {spec!r} holds no recordings")
    if skipped:
        typer.echo(f"using {len(recordings)} recordings; {len(skipped)} skipped (named above; "
                   "--strict stops at the first)", err=True)
    kinds = Counter(kind for r in recordings for kind in {p.kind for p in r.problems})
    if kinds:
        typer.echo("problems found on reading (kept, masked where they are): "
                   + ", ".join(f"{k} in {n} recording(s)" for k, n in sorted(kinds.items()))
                   + f"; `frictionfit info {spec}` lists them", err=True)
    return recordings


def problems_of(rec) -> str:
    """A recording's problems in one cell: ``[kind] words; ...`` (empty when clean)."""
    return "; ".join(f"[{p.kind}] {p}" for p in rec.problems)


def write_table(frame, out: Path) -> None:
    """``frame`` written to ``out``: Parquet for ``.parquet``, else CSV (no index)."""
    if out.suffix == ".parquet":
        frame.to_parquet(out, index=False)
    else:
        frame.to_csv(out, index=False)


def make_folder(path: Path, option: str) -> None:
    """Make the output folder ``path`` (and its parents) before any work is done; refuse,
    in words, one that cannot be made."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise typer.BadParameter(f"{path}: cannot make the folder ({exc.strerror})",
                                 param_hint=option) from None


#: The optional module that writes each kind of output file.
_WRITERS = {".parquet": "pyarrow", ".h5": "h5py", ".hdf5": "h5py", ".png": "matplotlib"}


def _check_writer(path: Path, option: str) -> None:
    """Refuse an output whose writer (an optional dependency) is not installed."""
    from frictionfit._optional import MissingExtraError, require

    if path.suffix in _WRITERS:
        try:
            require(_WRITERS[path.suffix], f"{option} {path.name}")
        except MissingExtraError as exc:
            raise typer.BadParameter(str(exc), param_hint=option) from exc


def check_writable(path: Path | None, option: str, suffixes: tuple[str, ...] = ()) -> None:
    """Refuse an output path that cannot be written, before any work is done."""
    if path is None:
        return
    if suffixes and path.suffix not in suffixes:
        raise typer.BadParameter(f"{path}: write {' or '.join(suffixes)}", param_hint=option)
    _check_writer(path, option)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise typer.BadParameter(f"{path}: folder {folder} does not exist", param_hint=option)
    if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise typer.BadParameter(f"{path}: not writable", param_hint=option)
