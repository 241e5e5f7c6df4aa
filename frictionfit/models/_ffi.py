"""What the contact loop's XLA target reads of XLA's FFI, and its check against the
``xla/ffi/api/c_api.h`` that the installed jaxlib ships.

The target (:mod:`frictionfit.models._xla`) is a C function that reads XLA's call frame,
buffers and metadata query at fixed byte offsets. This module holds those offsets, the
struct sizes and enumeration values it relies on, and the FFI versions it is written for
(:data:`KNOWN_VERSIONS`); :func:`layout_problem` parses the installed header and names any
difference, so that the target is never registered on a layout it does not know.
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["KNOWN_VERSIONS", "OFFSETS", "OPTIONAL_OFFSETS", "SIZES", "VALUES",
           "installed_header", "layout_problem", "parse_header"]

#: The XLA FFI versions (``XLA_FFI_API_MAJOR``, ``_MINOR``) whose layout the target is written
#: for, first and last: every field it reads sits at the same offset in each (0.2 and 0.3
#: extend 0.1's structs at their ends).
KNOWN_VERSIONS = ((0, 1), (0, 3))

#: Byte offsets of the fields the target reads or writes, ``(struct, field)``.
OFFSETS = {
    ("XLA_FFI_CallFrame", "struct_size"): 0,
    ("XLA_FFI_CallFrame", "extension_start"): 8,
    ("XLA_FFI_CallFrame", "api"): 16,
    ("XLA_FFI_CallFrame", "stage"): 32,
    ("XLA_FFI_CallFrame", "args"): 40,
    ("XLA_FFI_CallFrame", "rets"): 80,
    ("XLA_FFI_Args", "struct_size"): 0,
    ("XLA_FFI_Args", "size"): 16,
    ("XLA_FFI_Args", "types"): 24,
    ("XLA_FFI_Args", "args"): 32,
    ("XLA_FFI_Rets", "struct_size"): 0,
    ("XLA_FFI_Rets", "size"): 16,
    ("XLA_FFI_Rets", "types"): 24,
    ("XLA_FFI_Rets", "rets"): 32,
    ("XLA_FFI_Buffer", "struct_size"): 0,
    ("XLA_FFI_Buffer", "dtype"): 16,
    ("XLA_FFI_Buffer", "data"): 24,
    ("XLA_FFI_Buffer", "rank"): 32,
    ("XLA_FFI_Buffer", "dims"): 40,
    ("XLA_FFI_Extension_Base", "struct_size"): 0,
    ("XLA_FFI_Extension_Base", "type"): 8,
    ("XLA_FFI_Metadata_Extension", "metadata"): 24,
    ("XLA_FFI_Metadata", "struct_size"): 0,
    ("XLA_FFI_Metadata", "api_version"): 8,
    ("XLA_FFI_Metadata", "traits"): 32,
    ("XLA_FFI_Api_Version", "struct_size"): 0,
    ("XLA_FFI_Api_Version", "extension_start"): 8,
    ("XLA_FFI_Api_Version", "major_version"): 16,
    ("XLA_FFI_Api_Version", "minor_version"): 20,
    ("XLA_FFI_Api", "struct_size"): 0,
    ("XLA_FFI_Api", "api_version"): 16,
    ("XLA_FFI_Api", "XLA_FFI_Error_Create"): 48,
    ("XLA_FFI_Error_Create_Args", "message"): 16,
    ("XLA_FFI_Error_Create_Args", "errc"): 24,
}

#: Fields the target writes only where XLA's struct is long enough to have them (FFI 0.3's
#: ``state_type_id``): where a header has them, at these offsets.
OPTIONAL_OFFSETS = {("XLA_FFI_Metadata", "state_type_id"): 40}

#: ``<struct>_STRUCT_SIZE`` (bytes up to the field its traits name) of the structs read.
SIZES = {
    "XLA_FFI_CallFrame": 168,
    "XLA_FFI_Args": 40,
    "XLA_FFI_Rets": 40,
    "XLA_FFI_Buffer": 48,
    "XLA_FFI_Extension_Base": 24,
    "XLA_FFI_Metadata_Extension": 32,
    "XLA_FFI_Metadata": 36,
    "XLA_FFI_Api_Version": 24,
    "XLA_FFI_Error_Create_Args": 28,
}

#: Enumeration values the target compares with or writes.
VALUES = {
    "XLA_FFI_Extension_Metadata": 1,
    "XLA_FFI_DataType_S64": 5,
    "XLA_FFI_DataType_F64": 12,
    "XLA_FFI_ArgType_BUFFER": 1,
    "XLA_FFI_RetType_BUFFER": 1,
    "XLA_FFI_ExecutionStage_EXECUTE": 3,
    "XLA_FFI_Error_Code_INVALID_ARGUMENT": 3,
}

_SCALARS = {"size_t": 8, "int64_t": 8, "uint64_t": 8, "int": 4, "int32_t": 4, "uint32_t": 4}


def installed_header() -> Path | None:
    """The installed jaxlib's ``xla/ffi/api/c_api.h`` (None where jax has no FFI headers)."""
    import jax

    try:
        path = Path(jax.ffi.include_dir()) / "xla" / "ffi" / "api" / "c_api.h"
    except (AttributeError, OSError):  # a jax without jax.ffi.include_dir
        return None
    return path if path.is_file() else None


def _strip(text: str) -> str:
    """``text`` without its C comments."""
    return re.sub(r"//[^\n]*|/\*.*?\*/", "", text, flags=re.S)


def _enums(text: str) -> tuple[dict[str, int], set[str]]:
    """Every enumerator's value, and the names of 4-byte types (enums, ``uint32_t``
    typedefs)."""
    values, small = {}, set()
    for body, name in re.findall(r"typedef\s+enum\s*\{(.*?)\}\s*(\w+)\s*;", text, re.S):
        small.add(name)
        for member, value in re.findall(r"(\w+)\s*=\s*(\d+)", body):
            values[member] = int(value)
    for body in re.findall(r"\benum\s+\w*\s*\{(.*?)\}", text, re.S):
        for member, value in re.findall(r"(\w+)\s*=\s*([^,\s]+)", body):
            if value.isdigit():
                values[member] = int(value)
    small.update(re.findall(r"typedef\s+u?int32_t\s+(\w+)\s*;", text))
    return values, small


def _field(text: str) -> tuple[str, str]:
    """A struct field's type and name (``void (*f)(...)`` and ``T* x`` as pointers)."""
    text = re.sub(r"\b(const|struct)\b", "", text).strip()
    text = re.sub(r"_XLA_FFI_API_STRUCT_FIELD\((\w+)\)", r"\1* \1", text)
    if (pointer := re.search(r"\(\s*\*\s*(\w+)\s*\)", text)) is not None:
        return "*", pointer[1]
    kind, name = re.fullmatch(r"(.*?)\s*(\w+)", text).groups()
    return ("*" if "*" in kind else kind.strip()), name


def _structs(text: str, small: set[str]) -> dict[str, dict[str, tuple[int, int]]]:
    """Each struct's fields as ``name: (offset, size)`` (LP64: 8-byte pointers), and its
    size and alignment under ``""``; a struct with a field of a type not known here is
    left out."""
    out: dict[str, dict[str, tuple[int, int]]] = {}
    for name, body in re.findall(r"struct\s+(\w+)\s*\{(.*?)\}\s*\w*\s*;", text, re.S):
        fields, at, align = {}, 0, 1
        for kind, member in (_field(f) for f in body.split(";") if f.strip()):
            if kind == "*":
                size = al = 8
            elif kind in _SCALARS:
                size = al = _SCALARS[kind]
            elif kind in small:
                size = al = 4
            elif kind in out:
                size, al = out[kind][""]
            else:
                break
            at = -(-at // al) * al
            fields[member] = (at, size)
            at += size
            align = max(align, al)
        else:
            out[name] = fields | {"": (-(-at // align) * align, align)}
    return out


def parse_header(text: str) -> tuple[tuple[int, int], dict, dict, dict]:
    """The FFI version, the field offsets ``{(struct, field): byte}``, the struct sizes and
    the enumeration values that ``c_api.h``'s ``text`` defines."""
    text = _strip(text)
    major = re.search(r"#define\s+XLA_FFI_API_MAJOR\s+(\d+)", text)
    minor = re.search(r"#define\s+XLA_FFI_API_MINOR\s+(\d+)", text)
    if major is None or minor is None:
        raise ValueError("no XLA_FFI_API_MAJOR / XLA_FFI_API_MINOR")
    values, small = _enums(text)
    structs = _structs(text, small)
    offsets = {(s, f): o for s, fields in structs.items() for f, (o, _) in fields.items() if f}
    sizes = {}  # XLA_FFI_STRUCT_SIZE: up to the end of the field the traits name
    for name, last in re.findall(r"XLA_FFI_DEFINE_STRUCT_TRAITS\(\s*(\w+)\s*,\s*(\w+)", text):
        if last in structs.get(name, {}):
            sizes[name] = sum(structs[name][last])
    return (int(major[1]), int(minor[1])), offsets, sizes, values


def _versions(version: tuple[int, int]) -> str:
    """The known versions and ``version`` in words."""
    (a, b), (c, d) = KNOWN_VERSIONS
    return f"the contact loop's XLA target knows XLA FFI {a}.{b}-{c}.{d}; the installed " \
           f"jaxlib ships FFI {version[0]}.{version[1]}"


def layout_problem(header: Path | None = None) -> str | None:
    """None where ``header`` (default: :func:`installed_header`) defines every offset, size
    and value the target relies on as it expects them, within :data:`KNOWN_VERSIONS`; else
    what differs, naming both FFI versions."""
    import jax
    import jaxlib

    where = f"jax {jax.__version__}, jaxlib {jaxlib.__version__}"
    header = installed_header() if header is None else header
    if header is None:
        return f"{where} ships no xla/ffi/api/c_api.h to check the target's layout against"
    try:
        version, offsets, sizes, values = parse_header(header.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        return f"{header} could not be read as XLA's FFI header ({err})"
    if not KNOWN_VERSIONS[0] <= version <= KNOWN_VERSIONS[1]:
        return f"{_versions(version)} ({where}, {header})"
    wrong = [f"{s}.{f} at byte {offsets.get((s, f))} (expected {o})"
             for (s, f), o in OFFSETS.items() if offsets.get((s, f)) != o]
    wrong += [f"{s}.{f} at byte {offsets[(s, f)]} (expected {o})"
              for (s, f), o in OPTIONAL_OFFSETS.items() if offsets.get((s, f), o) != o]
    wrong += [f"{s}_STRUCT_SIZE {sizes.get(s)} (expected {n})"
              for s, n in SIZES.items() if sizes.get(s) != n]
    wrong += [f"{v} = {values.get(v)} (expected {n})"
              for v, n in VALUES.items() if values.get(v) != n]
    if wrong:
        return f"{_versions(version)} with another layout: {'; '.join(wrong)} ({where}, {header})"
    return None
