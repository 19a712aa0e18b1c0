"""Collect the real photographs that installed Debian and PyPI packages ship into one folder for
``MIPNET_PHOTOS`` (the photo pairs of :mod:`mipnet.data.photo_pairs`).

    python scripts/collect_photographs.py OUT [--licences permissive|all] [--root /] [--manifest FILE]

Which files of which package are real photographs (not renders, drawings, or stereo, depth or flow ground
truth), and under which licence the package's copyright file or metadata puts each, is data: the TOML manifest
``scripts/photo_sources.toml`` beside this script. For every source whose package is installed under ``--root``
the script copies the photographs the licence policy admits into ``OUT/<source>/<name as in the package>`` and
writes ``OUT/SOURCES.md`` (package, version, licence, count, per-photo attribution). For the sources that are not
installed it prints the one ``apt-get install ...`` / ``pip install ...`` line that would add them; it never
installs anything.

``--licences permissive`` (the default) takes public domain, CC0, CC-BY-*, CC-BY-SA-*, MIT/Expat, Apache-2.0 and
BSD; ``all`` adds GPL and LGPL. A file whose licence is anything else, or whose licence in the manifest disagrees
with the package's copyright file, is not copied (one warning line). Files whose names look like ground truth
(:data:`REFUSED_NAMES`) are never copied, whatever the manifest says. Every file is written to a temporary name and
renamed, so an interrupted run leaves no half-written photograph; image files in ``OUT/<source>`` that this run
did not select (an earlier run under another policy) are removed. A corrupt or unreadable image is skipped with
one warning line naming it.

The manifest, per ``[[source]]``:

``name``
    the folder under OUT.
``manager``, ``package``
    ``apt`` (installed: listed as installed in ``ROOT/var/lib/dpkg/status``) or ``pip`` (installed: a
    ``*.dist-info`` of that name in one of this interpreter's ``sys.path`` folders, taken under ROOT).
``base``
    where the files are: a folder under ROOT (apt), a folder inside the distribution (pip), or for ``rcc``
    sources the resource path the names are relative to.
``rcc``
    optional glob under ROOT of Qt binary resource bundles (``.rcc``) that hold the files (see :func:`read_rcc`).
``copyright``
    optional DEP-5 copyright file under ROOT (apt); ``copyright_prefix``: what to put before a photo's relative
    name to get its path in that file; ``copyright_any_suffix``: the file names the photo with another extension
    (the package converted it, e.g. to ``.webp``).
``exclude``
    globs of relative names never taken.
``[[source.files]]``
    ``licence`` (as the copyright file or the package metadata states it) and ``include``: relative names or globs.
"""

from __future__ import annotations

import argparse
import fnmatch
import io
import os
import re
import struct
import sys
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

MANIFEST = Path(__file__).with_name("photo_sources.toml")
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp"}
#: Name patterns of stereo partners and ground truth (disparity, depth, Middlebury ``im0``/``im1``, ``GT``):
#: a file any part of whose relative name matches one is never copied. ``*GT*`` is matched case-sensitively
#: (so that "length" passes), the others in any case.
REFUSED_NAMES = ("*disp*", "*depth*", "im0*", "im1*", "*GT*")
_CASE_SENSITIVE = {"*GT*"}

#: Licence names (as Debian copyright files and package metadata write them, in any case) by kind.
PERMISSIVE = (r"public[- ]domain", r"cc0(-1\.0)?", r"cc-by(-sa)?(-\d+(\.\d+)?)?", r"mit", r"expat",
              r"apache(-\d+(\.\d+)?)?", r"bsd(-[234]-clause)?")
COPYLEFT = (r"l?gpl(-\d+(\.\d+)?)?(\+|-only|-or-later)?",)


def warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


# --------------------------------------------------------------------------------------------------- Qt .rcc


def read_rcc(data: bytes) -> dict[str, bytes | None]:
    """The files of a Qt binary resource bundle (``rcc -binary`` output, format versions 1-3), path -> bytes.

    Layout (all integers big-endian; offsets are from the start of the file unless said otherwise)::

        header   b"qres", u32 version, u32 tree offset, u32 data offset, u32 names offset
                 [, u32 flags when version >= 3]
        tree     an array of entries, 14 bytes each in version 1, 22 in versions 2 and 3; entry 0 is the root
                 folder. Every entry starts with u32 name offset (into names), u16 flags
                 (1: zlib-compressed, 2: folder, 4: zstd-compressed), then
                 folder: u32 child count, u32 index of the first child (children are consecutive entries);
                 file:   u16 territory, u16 language, u32 data offset (into data);
                 versions >= 2 then add u64 last-modified time (ms since the epoch).
        names    at a name offset: u16 length in UTF-16 units, u32 hash, then the name in UTF-16BE.
        data     at a data offset: u32 size, then that many bytes. A zlib-compressed file's bytes are
                 qCompress output: u32 uncompressed size, then a zlib stream.

    The path of a file is its folders' names and its own joined with "/" after a leading "/" (the root has no
    name). A file stored compressed with zstd (Qt 6 only) maps to None. A bundle that is not in this format
    raises ValueError.
    """
    if data[:4] != b"qres" or len(data) < 20:
        raise ValueError("not a Qt binary resource (.rcc) file")
    version, tree, blobs, names = struct.unpack_from(">IIII", data, 4)
    if not 1 <= version <= 3:
        raise ValueError(f"unsupported .rcc format version {version}")
    entry_size = 14 if version == 1 else 22

    def name_at(offset: int) -> str:
        (length,) = struct.unpack_from(">H", data, names + offset)
        start = names + offset + 6  # after the length and the hash
        return data[start:start + 2 * length].decode("utf-16-be")

    files: dict[str, bytes | None] = {}
    try:
        pending = [(0, "")]  # (entry index, path of the folder holding it)
        seen = set()
        while pending:
            index, folder = pending.pop()
            if index in seen:
                raise ValueError("the resource tree has a cycle")
            seen.add(index)
            entry = tree + index * entry_size
            name_offset, flags = struct.unpack_from(">IH", data, entry)
            path = f"{folder}/{name_at(name_offset)}" if index else ""
            if flags & 2:
                count, first = struct.unpack_from(">II", data, entry + 6)
                pending.extend((child, path) for child in range(first, first + count))
                continue
            (blob_offset,) = struct.unpack_from(">I", data, entry + 10)
            (size,) = struct.unpack_from(">I", data, blobs + blob_offset)
            blob = data[blobs + blob_offset + 4:blobs + blob_offset + 4 + size]
            if len(blob) != size:
                raise ValueError(f"{path}: data runs past the end of the file")
            if flags & 1:
                blob = zlib.decompress(blob[4:])
            elif flags & 4:
                blob = None
            files[path] = blob
    except (struct.error, UnicodeDecodeError, zlib.error, ValueError) as error:
        raise ValueError(f"corrupt .rcc file ({error})") from error
    return files


# --------------------------------------------------------------------------------------- DEP-5 copyright


@dataclass
class Stanza:
    """One ``Files:`` paragraph of a machine-readable (DEP-5) Debian copyright file."""

    patterns: list[str]
    copyright: str
    licence: str
    comment: str = ""


def _paragraphs(text: str) -> list[dict[str, str]]:
    paragraphs, current, key = [], {}, None
    for line in text.splitlines():
        if not line.strip():
            if current:
                paragraphs.append(current)
            current, key = {}, None
        elif line.startswith("#"):
            continue
        elif line[0] in " \t" and key is not None:
            current[key] += "\n" + line.strip()
        elif ":" in line:
            key, value = line.split(":", 1)
            key = key.strip().lower()
            current[key] = value.strip()
    if current:
        paragraphs.append(current)
    return paragraphs


def read_copyright(text: str) -> list[Stanza]:
    """The ``Files:`` stanzas of a DEP-5 copyright file, in file order (the last one that matches a path wins)."""
    stanzas = []
    for paragraph in _paragraphs(text):
        if "files" in paragraph and "license" in paragraph:
            stanzas.append(Stanza(paragraph["files"].split(),
                                  " ".join(paragraph.get("copyright", "").split()),
                                  paragraph["license"].split("\n")[0].strip(),
                                  paragraph.get("comment", "").split("\n")[0].strip()))
    return stanzas


def _dep5_match(pattern: str, path: str, any_suffix: bool) -> bool:
    # DEP-5 wildcards: "*" matches any run of characters including "/", "?" one character.
    regex = "".join(".*" if ch == "*" else "." if ch == "?" else re.escape(ch) for ch in pattern)
    if re.fullmatch(regex, path):
        return True
    if any_suffix and "*" not in pattern and "?" not in pattern:
        return PurePosixPath(pattern).with_suffix("").as_posix() == PurePosixPath(path).with_suffix("").as_posix()
    return False


def stanza_for(stanzas: list[Stanza], path: str, any_suffix: bool = False) -> tuple[Stanza, list[str]] | None:
    """The stanza that governs ``path`` (the last one with a matching pattern) and its patterns that match, or
    None. A matching pattern without wildcard names the file itself: the stanza's Copyright line is then that
    file's attribution."""
    for stanza in reversed(stanzas):
        matching = [p for p in stanza.patterns if _dep5_match(p, path, any_suffix)]
        if matching:
            return stanza, matching
    return None


def _is_wildcard(pattern: str) -> bool:
    return "*" in pattern or "?" in pattern


# --------------------------------------------------------------------------------------------- licences


def licence_kind(licence: str) -> str | None:
    """``"permissive"``, ``"copyleft"`` or None (anything else) for a licence as a copyright file writes it.

    ``A and B`` needs both; ``A or B`` takes the freer of the two."""
    text = licence.strip().lower()
    if " or " in text:
        kinds = [licence_kind(part) for part in re.split(r"\s+or\s+", text)]
        return "permissive" if "permissive" in kinds else "copyleft" if "copyleft" in kinds else None
    if " and " in text or "," in text:
        kinds = [licence_kind(part) for part in re.split(r"\s+and\s+|,", text) if part.strip()]
        return None if None in kinds else "copyleft" if "copyleft" in kinds else "permissive"
    if any(re.fullmatch(pattern, text) for pattern in PERMISSIVE):
        return "permissive"
    if any(re.fullmatch(pattern, text) for pattern in COPYLEFT):
        return "copyleft"
    return None


def admitted(licence: str, policy: str) -> bool:
    kind = licence_kind(licence)
    return kind == "permissive" or (kind == "copyleft" and policy == "all")


def refused_name(relative: str) -> str | None:
    """The ground-truth pattern that some part of ``relative`` matches, or None."""
    for part in PurePosixPath(relative).parts:
        for pattern in REFUSED_NAMES:
            if pattern in _CASE_SENSITIVE:
                if fnmatch.fnmatchcase(part, pattern):
                    return pattern
            elif fnmatch.fnmatchcase(part.lower(), pattern.lower()):
                return pattern
    return None


# ---------------------------------------------------------------------------------------------- packages


def _under(root: Path, path: str) -> Path:
    """``path`` (absolute on the target system) as a path under ``root``."""
    return root / str(path).lstrip("/")


def installed_debs(root: Path) -> dict[str, str]:
    """package -> version of the packages that ``ROOT/var/lib/dpkg/status`` lists as installed."""
    status = _under(root, "/var/lib/dpkg/status")
    if not status.is_file():
        return {}
    found = {}
    for paragraph in _paragraphs(status.read_text(encoding="utf-8", errors="replace")):
        if paragraph.get("status", "").endswith(" installed") and "package" in paragraph:
            found[paragraph["package"]] = paragraph.get("version", "?")
    return found


def pip_distribution(root: Path, package: str):
    """The installed distribution ``package`` (found in this interpreter's ``sys.path``, under ROOT), or None."""
    import importlib.metadata

    path = [str(_under(root, entry)) for entry in sys.path if entry and os.path.isabs(entry)]
    wanted = re.sub(r"[-_.]+", "-", package).lower()
    for dist in importlib.metadata.distributions(path=path):
        if re.sub(r"[-_.]+", "-", dist.metadata.get("Name", "")).lower() == wanted:
            return dist
    return None


# ----------------------------------------------------------------------------------------------- sources


@dataclass
class Photo:
    """A photograph selected from a source, with where its licence comes from."""

    relative: str  # name inside the source folder, as in the package
    licence: str
    attribution: str = ""  # from a copyright stanza that names this file
    read: object = None  # () -> bytes
    general: Stanza | None = None  # the wildcard copyright stanza that covers it, if that is what governs it
    patterns: tuple = ()  # general's patterns that match it


@dataclass
class Source:
    """A ``[[source]]`` of the manifest, what is installed of it, and the photographs selected from it."""

    spec: dict
    version: str | None = None  # None: not installed
    dist: object = None  # the importlib.metadata distribution of a pip source
    stated: str = ""  # the licence the package metadata states (pip)
    photos: list[Photo] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.spec["name"]


def load_manifest(path: Path) -> list[dict]:
    with open(path, "rb") as f:
        sources = tomllib.load(f).get("source", [])
    names = [s["name"] for s in sources]
    if len(set(names)) != len(names):
        raise SystemExit(f"{path}: two sources share a name")
    for s in sources:
        if s.get("manager") not in ("apt", "pip"):
            raise SystemExit(f"{path}: source {s.get('name')!r}: manager must be apt or pip")
        for group in s.get("files", []):
            if "licence" not in group or "include" not in group:
                raise SystemExit(f"{path}: source {s['name']!r}: every [[source.files]] needs licence and include")
    return sources


def _available_files(source: Source, root: Path) -> dict[str, object]:
    """relative name -> reader of every file the source's package holds under its base."""
    spec = source.spec
    base = spec["base"].strip("/")
    if spec.get("rcc"):
        found = {}
        for bundle in sorted(root.glob(spec["rcc"].lstrip("/"))):
            try:
                files = read_rcc(bundle.read_bytes())
            except (OSError, ValueError) as error:
                warn(f"{bundle}: unreadable resource bundle skipped ({error})")
                continue
            for path, blob in files.items():
                path = path.lstrip("/")
                if path.startswith(base + "/"):
                    found[path[len(base) + 1:]] = (lambda b=blob: b) if blob is not None else None
        return found
    if spec["manager"] == "pip":
        folder = Path(source.dist.locate_file(base))
    else:
        folder = _under(root, base)
    return {p.relative_to(folder).as_posix(): p.read_bytes for p in sorted(folder.rglob("*")) if p.is_file()}


def select(source: Source, root: Path, policy: str) -> None:
    """Fill ``source.photos`` with the manifest's photographs that exist and that the policy admits."""
    spec = source.spec
    available = _available_files(source, root)
    stanzas = []
    if spec.get("copyright"):
        copyright_file = _under(root, spec["copyright"])
        if copyright_file.is_file():
            stanzas = read_copyright(copyright_file.read_text(encoding="utf-8", errors="replace"))
        else:
            warn(f"{source.name}: no copyright file {copyright_file}")
    stated = None
    if spec["manager"] == "pip":
        meta = source.dist.metadata
        stated = meta.get("License-Expression") or meta.get("License")
    excluded = spec.get("exclude", [])
    taken = set()
    for group in spec.get("files", []):
        licence = group["licence"]
        for pattern in group["include"]:
            matches = sorted(n for n in available if fnmatch.fnmatchcase(n, pattern))
            if not matches and not any(ch in pattern for ch in "*?["):
                warn(f"{source.name}: {pattern} is not in the installed package")
            for relative in matches:
                if relative in taken:
                    continue
                taken.add(relative)
                if PurePosixPath(relative).suffix.lower() not in IMAGE_SUFFIXES:
                    continue
                if any(fnmatch.fnmatchcase(relative, ex) or fnmatch.fnmatchcase(PurePosixPath(relative).name, ex)
                       for ex in excluded):
                    continue
                pattern_hit = refused_name(relative)
                if pattern_hit:
                    warn(f"{source.name}: {relative} refused: its name matches {pattern_hit} (ground truth)")
                    continue
                attribution, general = "", None
                if stanzas:
                    found = stanza_for(stanzas, spec.get("copyright_prefix", "") + relative,
                                       spec.get("copyright_any_suffix", False))
                    if found is None:
                        warn(f"{source.name}: {relative} skipped: the copyright file does not cover it")
                        continue
                    stanza, matching = found
                    if stanza.licence.lower() != licence.lower():
                        warn(f"{source.name}: {relative} skipped: the manifest says {licence}, "
                             f"the copyright file {stanza.licence}")
                        continue
                    if not all(_is_wildcard(p) for p in matching):
                        attribution = stanza.copyright
                        if stanza.comment.startswith("http"):
                            attribution += f", {stanza.comment}"
                    else:
                        general = stanza
                elif stated is not None and stated.lower() != licence.lower():
                    warn(f"{source.name}: {relative} skipped: the manifest says {licence}, the package {stated}")
                    continue
                if not admitted(licence, policy):
                    if licence_kind(licence) is None:
                        warn(f"{source.name}: {relative} skipped: licence {licence} is neither permissive nor GPL/LGPL")
                    else:  # GPL/LGPL under the permissive policy
                        source.skipped.append(relative)
                    continue
                if available[relative] is None:
                    warn(f"{source.name}: {relative} skipped: stored compressed with zstd, which this reader lacks")
                    continue
                source.photos.append(Photo(relative, licence, attribution, available[relative], general,
                                           tuple(matching) if general else ()))
    source.stated = stated or ""


# ---------------------------------------------------------------------------------------------- writing


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as f:
            f.write(data)
        os.replace(temporary, path)
    except BaseException:
        os.unlink(temporary)
        raise


def _check_image(data: bytes) -> str | None:
    """None if Pillow decodes ``data`` completely, else why not."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as image:
            image.verify()
        with Image.open(io.BytesIO(data)) as image:
            image.load()
            if min(image.size) < 16:
                return f"only {image.size[0]}x{image.size[1]} pixels"
    except (OSError, SyntaxError, ValueError, EOFError, struct.error, zlib.error,
            Image.DecompressionBombError) as error:  # what Pillow raises for broken or hostile files
        return f"{type(error).__name__}: {error}"
    return None


def copy_photos(source: Source, out: Path) -> int:
    """Copy the selected photographs into ``out/<source>``; drop the unreadable ones (with a warning) and the
    image files there that this run did not select. Returns the number written."""
    folder = out / source.name
    kept = []
    for photo in source.photos:
        try:
            data = photo.read()
        except OSError as error:
            warn(f"{source.name}: {photo.relative} skipped: unreadable ({error})")
            continue
        problem = _check_image(data)
        if problem:
            warn(f"{source.name}: {photo.relative} skipped: not a readable image ({problem})")
            continue
        target = folder / photo.relative
        if not (target.is_file() and target.read_bytes() == data):
            _atomic_write(target, data)
        kept.append(photo)
    source.photos = kept
    prune(folder, {p.relative for p in kept})
    return len(kept)


def prune(folder: Path, keep: set[str]) -> None:
    """Remove the image files (and leftover temporary files) under ``folder`` not named in ``keep``."""
    if not folder.is_dir():
        return
    stale = [p for p in folder.rglob("*") if p.is_file() and p.relative_to(folder).as_posix() not in keep
             and (p.suffix.lower() in IMAGE_SUFFIXES or p.name.endswith(".tmp"))]
    for path in stale:
        path.unlink()
    for sub in sorted((p for p in folder.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
        if not any(sub.iterdir()):
            sub.rmdir()
    if folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()
    if stale:
        print(f"{folder.name}: removed {len(stale)} photographs of an earlier run")


def sources_markdown(sources: list[Source], policy: str) -> str:
    admitted_text = "public domain, CC0, CC-BY, CC-BY-SA, MIT/Expat, Apache-2.0, BSD" + (
        ", GPL, LGPL" if policy == "all" else "")
    lines = ["# Photographs for photo pairs", "",
             (f"Collected by `scripts/collect_photographs.py` from installed packages (licences: {policy}: "
              f"{admitted_text})."), ""]
    total = sum(len(s.photos) for s in sources)
    lines += [f"{total} photographs from {sum(1 for s in sources if s.photos)} sources.", "",
              "| folder | package | version | licence | photographs |", "| --- | --- | --- | --- | --- |"]
    for s in sources:
        if s.photos:
            licences = ", ".join(sorted({p.licence for p in s.photos}))
            lines.append(f"| {s.name} | {s.spec['package']} ({s.spec['manager']}) | {s.version} | {licences} | "
                         f"{len(s.photos)} |")
    for s in sources:
        if not s.photos:
            continue
        lines += ["", f"## {s.name}", "",
                  f"Package `{s.spec['package']}` {s.version} ({s.spec['manager']}); {len(s.photos)} photographs."]
        if s.spec.get("copyright"):
            lines.append(f"Licences as `{s.spec['copyright']}` states them.")
        if s.stated:
            lines.append(f"Licence as the package metadata states it: {s.stated}.")
        if s.spec.get("note"):
            lines.append(" ".join(s.spec["note"].split()))
        general: dict[int, tuple[Stanza, dict]] = {}
        for photo in s.photos:
            if photo.general is not None:
                general.setdefault(id(photo.general), (photo.general, {}))[1].update(dict.fromkeys(photo.patterns))
        for stanza, patterns in general.values():
            more = len(stanza.patterns) - len(patterns)
            lines.append(f"- Files: `{' '.join(patterns)}`" + (f" (and {more} more patterns)" if more else "")
                         + f" - Copyright: {stanza.copyright or '(none given)'} - License: {stanza.licence}")
        lines += ["", "| file | licence | attribution |", "| --- | --- | --- |"]
        for photo in sorted(s.photos, key=lambda p: p.relative):
            cell = photo.attribution.replace("|", "\\|") or "-"
            lines.append(f"| {photo.relative} | {photo.licence} | {cell} |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="the collection folder (for MIPNET_PHOTOS)")
    p.add_argument("--licences", choices=("permissive", "all"), default="permissive",
                   help="permissive (default): public domain, CC0, CC-BY(-SA), MIT, Apache, BSD; all: also GPL/LGPL")
    p.add_argument("--root", type=Path, default=Path("/"), help="the file system the packages are installed in")
    p.add_argument("--manifest", type=Path, default=MANIFEST, help="the photo source list (TOML)")
    args = p.parse_args(argv)

    debs = installed_debs(args.root)
    sources, missing = [], {"apt": [], "pip": []}
    for spec in load_manifest(args.manifest):
        source = Source(spec)
        if spec["manager"] == "apt":
            source.version = debs.get(spec["package"])
        else:
            source.dist = pip_distribution(args.root, spec["package"])
            source.version = source.dist.version if source.dist is not None else None
        if source.version is None:
            if any(admitted(g["licence"], args.licences) for g in spec.get("files", [])):
                missing[spec["manager"]].append(spec["package"])
            prune(args.out / source.name, set())
            continue
        select(source, args.root, args.licences)
        count = copy_photos(source, args.out)
        extra = ""
        if source.skipped and args.licences != "all":
            extra = f" ({len(source.skipped)} more with --licences all)"
        print(f"{source.name}: {count} photographs{extra}")
        sources.append(source)
    _atomic_write(args.out / "SOURCES.md", sources_markdown(sources, args.licences).encode())
    total = sum(len(s.photos) for s in sources)
    print(f"{total} photographs in {args.out} (listed in {args.out / 'SOURCES.md'})")
    for manager, packages in missing.items():
        if packages:
            command = "apt-get install" if manager == "apt" else "pip install"
            print(f"not installed, to add them: {command} {' '.join(dict.fromkeys(packages))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
