"""What a command reads and writes: recordings read with the files skipped named on stderr and
counts said; outputs checked before any work (never a recording, nor a file the command reads;
an existing one replaced only with ``--overwrite``); a line per stage of a long command."""

from __future__ import annotations

import json
import os
import warnings
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import typer

STRICT_HELP = ("Stop at the first recording that cannot be used (default: skip it, naming it "
               "and why).")
#: The whole-measurement fits' laws, as the commands that fit them explain them.
WHOLE_LAWS_HELP = ("auto (by BIC: no static peak, a static peak, or a static peak with viscous "
                   "damping), no_peak2, relaxation, relaxation2 or rich.")


#: Skipped files named when none of a dataset's could be used (the error counts the reasons).
SHOWN_WHEN_NONE = 10


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

    failure, recordings = None, []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        try:
            recordings = load_dataset(spec, strict=strict)
        except FrictionfitError as exc:
            failure = str(exc)
    skipped = [w for w in caught if issubclass(w.category, DatasetWarning)]
    for w in caught:
        if w not in skipped:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    # every file skipped is named; when none could be used, the first few and the reasons
    shown = skipped if failure is None else skipped[:SHOWN_WHEN_NONE]
    for w in shown:
        typer.echo(str(w.message), err=True)
    if failure is not None:
        if len(skipped) > len(shown):
            typer.echo(f"... and {len(skipped) - len(shown)} more skipped", err=True)
        fail(failure)
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


OVERWRITE_HELP = ("Replace an existing output file (never a recording, nor a file the command "
                  "reads: those are refused whatever this says).")


def is_recording(path: Path) -> bool:
    """Whether ``path`` is part of a recording a reader recognises: a ``<name>.csv`` +
    ``<name>.json`` pair, a sidecar (a JSON object with ``sample_rate_hz`` and
    ``channels``), or a FabricSlide slide."""
    from frictionfit.recording import looks_like_fabricslide, recording_paths

    if not path.exists():
        return False
    path = path.resolve()  # a link to a recording's file is that file
    if path.suffix not in (".csv", ".json"):
        return False
    csv, side = recording_paths(path)
    if csv.is_file() and side.is_file():
        return True
    if path.suffix == ".csv":
        return looks_like_fabricslide(path)
    try:
        head = json.loads(path.read_text(errors="replace"))
    except (OSError, ValueError):
        return False
    return isinstance(head, dict) and {"sample_rate_hz", "channels"} <= set(head)


def dataset_reads(spec: str) -> list[Path]:
    """The files a ``KIND:PATH`` dataset spec reads (:func:`reads_of` its path)."""
    _, sep, path = spec.partition(":")
    return reads_of([Path(path)]) if sep and path else []


def reads_of(paths: list[Path]) -> list[Path]:
    """The files a command that reads the recordings (or dataset folders) ``paths`` reads:
    each recording's CSV and sidecar, and every .csv, .json and .npz file of a folder."""
    from frictionfit.recording import recording_paths

    out = []
    for p in paths:
        if p.is_dir():
            out += [f for f in p.rglob("*") if f.suffix in (".csv", ".json", ".npz")]
        else:
            out += [p, *recording_paths(p)]
    return out


def check_output(path: Path | None, option: str, suffixes: tuple[str, ...] = (), *,
                 overwrite: bool = False, reads: list[Path] = (), replaces: bool = True) -> None:
    """Refuse, before any work is done, an output path that cannot be written (see
    :func:`check_writable`), that is a recording (:func:`is_recording`) or a file the
    command reads (``reads``), whatever ``overwrite`` says, or that exists already unless
    ``overwrite`` (``replaces=False``: the command adds to the file instead)."""
    if path is None:
        return
    check_writable(path, option, suffixes)
    if is_recording(path):
        raise typer.BadParameter(f"{path} is a recording: frictionfit never writes over a "
                                 "recording; choose another name", param_hint=option)
    here = path.resolve()
    if any(here == Path(r).resolve() for r in reads):
        raise typer.BadParameter(f"{path} is a file this command reads: choose another name",
                                 param_hint=option)
    if replaces and path.exists() and not overwrite:
        raise typer.BadParameter(f"{path} exists: add --overwrite to replace it, or choose "
                                 "another name", param_hint=option)


@contextmanager
def stage(words: str):
    """A stage of a long command: on a terminal a spinner with ``words`` while it runs;
    otherwise (a log, a pipe) a ``words ...`` line on stderr when it starts. Either way a
    line with its duration (s) when it ends."""
    import sys
    import time

    start = time.perf_counter()
    if sys.stderr.isatty():
        from rich.console import Console

        with Console(stderr=True).status(words):
            yield
    else:
        typer.echo(f"{words} ...", err=True)
        yield
    typer.echo(f"{words}: done in {time.perf_counter() - start:.1f} s", err=True)
