"""scripts/collect_photographs.py on a fake installed system: a dpkg status file, packages' files and DEP-5
copyright files, a Qt .rcc bundle and a pip distribution, all made here (none of the real packages is needed)."""

import importlib.util
import io
import os
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from mipnet.data import photographs
from PIL import Image, features

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "collect_photographs.py"


@pytest.fixture
def collect(monkeypatch):
    """The script as a module."""
    spec = importlib.util.spec_from_file_location("collect_photographs", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def image_bytes(fmt: str, seed: int, size=(40, 30)) -> bytes:
    pixels = np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format=fmt)
    return buffer.getvalue()


def make_rcc(files: dict[str, bytes], compressed=(), zstd=(), version=2) -> bytes:
    """A Qt binary resource bundle holding ``files`` (path -> bytes), laid out as read_rcc's docstring says."""
    # The folder tree, root first; every folder's children get consecutive entries.
    tree = {}
    for path in files:
        node = tree
        for part in path.strip("/").split("/"):
            node = node.setdefault(part, {})
    entries, names, blobs = [], bytearray(), bytearray()
    name_offsets = {}

    def name_offset(name):
        if name not in name_offsets:
            name_offsets[name] = len(names)
            encoded = name.encode("utf-16-be")
            names.extend(struct.pack(">HI", len(encoded) // 2, 0) + encoded)
        return name_offsets[name]

    queue = [("", "", tree)]  # (name, path, children or None) in entry order
    entries.append(None)
    index_of = {"": 0}
    position = 0
    while position < len(queue):
        name, path, children = queue[position]
        if children:  # a folder: its children come next, consecutively
            first = len(entries)
            for child in sorted(children):
                child_path = f"{path}/{child}"
                index_of[child_path] = len(entries)
                entries.append(None)
                queue.append((child, child_path, children[child] or None))
            entries[index_of[path]] = struct.pack(">IHII", name_offset(name) if path else 0, 2, len(children), first)
        else:
            blob = files[path]
            flags = 0
            if path in compressed:
                blob, flags = struct.pack(">I", len(blob)) + zlib.compress(blob), 1
            elif path in zstd:
                flags = 4
            entries[index_of[path]] = struct.pack(">IHHHI", name_offset(name), flags, 0, 0, len(blobs))
            blobs.extend(struct.pack(">I", len(blob)) + blob)
        position += 1
    extra = 8 if version >= 2 else 0
    table = b"".join(entry + bytes(extra) for entry in entries)
    header_size = 24 if version >= 3 else 20
    tree_offset = header_size
    data_offset = tree_offset + len(table)
    names_offset = data_offset + len(blobs)
    header = b"qres" + struct.pack(">IIII", version, tree_offset, data_offset, names_offset)
    if version >= 3:
        header += struct.pack(">I", 0)
    return header + table + bytes(blobs) + bytes(names)


PHOTOS_COPYRIGHT = """\
Format: https://www.debian.org/doc/packaging-manuals/copyright-format/1.0/
Upstream-Name: fake-photos

Files: *
Copyright: 2020 Fake Authors
License: public-domain

Files: Nature/lake.jpg
Copyright: Jane Doe
License: CC-BY-SA-3.0
Comment: https://example.org/lake

Files: Nature/mismatch.jpg
Copyright: John Roe
License: GPL-3+

Files: Nature/nc.jpg
Copyright: Nora Commons
License: CC-BY-NC-2.0

License: CC-BY-SA-3.0
 The licence text.
"""

RCC_COPYRIGHT = """\
Format: https://www.debian.org/doc/packaging-manuals/copyright-format/1.0/

Files: *
Copyright: The RCC authors
License: GPL-3+

Files: src/photos/fish.jpg
Copyright: Ann Diver
License: CC-BY-2.0
Comment: https://example.org/fish

Files: src/photos/sub/*
Copyright: Reef Society
License: CC0-1.0
"""

MANIFEST = """\
[[source]]
name = "fake-photos"
manager = "apt"
package = "fake-photos"
base = "/usr/share/fake-photos"
copyright = "/usr/share/doc/fake-photos/copyright"
exclude = ["left*"]

[[source.files]]
licence = "CC-BY-SA-3.0"
include = ["Nature/lake.jpg"]

[[source.files]]
licence = "public-domain"
include = ["Nature/*.png", "Nature/left01.jpg", "broken.jpg", "frame_GT.jpg", "notes.txt"]

[[source.files]]
licence = "CC0-1.0"
include = ["Nature/mismatch.jpg", "Nature/not-there.jpg"]

[[source.files]]
licence = "CC-BY-NC-2.0"
include = ["Nature/nc.jpg"]

[[source]]
name = "fake-gpl"
manager = "apt"
package = "fake-gpl"
base = "/usr/share/fake-gpl"

[[source.files]]
licence = "GPL-2+"
include = ["castle.jpg"]

[[source]]
name = "fake-rcc"
manager = "apt"
package = "fake-rcc"
rcc = "/usr/share/fake-rcc/*.rcc"
base = "/app/photos"
copyright = "/usr/share/doc/fake-rcc/copyright"
copyright_prefix = "src/photos/"
copyright_any_suffix = true

[[source.files]]
licence = "CC-BY-2.0"
include = ["fish.webp"]

[[source.files]]
licence = "CC0-1.0"
include = ["sub/*.webp"]

[[source.files]]
licence = "GPL-3+"
include = ["seal.webp"]

[[source]]
name = "fake-pip"
manager = "pip"
package = "fake-pip-photos"
base = "fake_pip_photos/images"

[[source.files]]
licence = "MIT"
include = ["*.jpg"]

[[source]]
name = "absent"
manager = "apt"
package = "absent-pkg"
base = "/usr/share/absent"

[[source.files]]
licence = "CC0-1.0"
include = ["*.jpg"]

[[source]]
name = "absent-gpl"
manager = "apt"
package = "absent-gpl-pkg"
base = "/usr/share/absent-gpl"

[[source.files]]
licence = "GPL-2+"
include = ["*.jpg"]

[[source]]
name = "absent-pip"
manager = "pip"
package = "absent-pip-photos"
base = "absent"

[[source.files]]
licence = "MIT"
include = ["*.jpg"]
"""

WEBP = "WEBP" if features.check("webp") else "PNG"


def write(path: Path, data) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        path.write_text(data)
    else:
        path.write_bytes(data)
    return path


@pytest.fixture
def system(tmp_path):
    """A fake installed system under tmp_path/root; returns (root, manifest, the files' bytes by output name)."""
    root = tmp_path / "root"
    status = "".join(f"Package: {name}\nStatus: install ok installed\nVersion: {version}\n\n"
                     for name, version in [("fake-photos", "1.2-3"), ("fake-gpl", "4.5"), ("fake-rcc", "0.9-1")])
    status += "Package: absent-pkg\nStatus: deinstall ok config-files\nVersion: 1.0\n"
    write(root / "var/lib/dpkg/status", status)
    share = root / "usr/share"
    content = {
        "fake-photos/Nature/lake.jpg": image_bytes("JPEG", 1),
        "fake-photos/Nature/tree.png": image_bytes("PNG", 2),
        "fake-photos/Nature/im0.png": image_bytes("PNG", 3),  # Middlebury-style stereo view: refused
        "fake-photos/Nature/scene_disp.png": image_bytes("PNG", 4),  # disparity ground truth: refused
        "fake-photos/Nature/left01.jpg": image_bytes("JPEG", 5),  # excluded by the manifest
        "fake-photos/Nature/mismatch.jpg": image_bytes("JPEG", 6),  # manifest and copyright disagree
        "fake-photos/Nature/nc.jpg": image_bytes("JPEG", 15),  # non-commercial: never taken
        "fake-photos/frame_GT.jpg": image_bytes("JPEG", 7),  # ground truth: refused
        "fake-photos/broken.jpg": image_bytes("JPEG", 8)[:60],  # truncated: skipped with a warning
        "fake-photos/notes.txt": b"not an image",
        "fake-gpl/castle.jpg": image_bytes("JPEG", 9),
    }
    for name, data in content.items():
        write(share / name, data)
    write(share / "doc/fake-photos/copyright", PHOTOS_COPYRIGHT)
    write(share / "doc/fake-rcc/copyright", RCC_COPYRIGHT)
    rcc_files = {
        "/app/photos/fish.webp": image_bytes(WEBP, 10),
        "/app/photos/sub/reef.webp": image_bytes(WEBP, 11),
        "/app/photos/seal.webp": image_bytes(WEBP, 12),
        "/app/icons/logo.png": image_bytes("PNG", 13),
    }
    write(share / "fake-rcc/app.rcc", make_rcc(rcc_files, compressed={"/app/photos/fish.webp"}))
    content.update({"fake-rcc/fish.webp": rcc_files["/app/photos/fish.webp"],
                    "fake-rcc/sub/reef.webp": rcc_files["/app/photos/sub/reef.webp"],
                    "fake-rcc/seal.webp": rcc_files["/app/photos/seal.webp"]})
    # A pip distribution in (the fake root's copy of) one of this interpreter's sys.path folders.
    site = next((entry for entry in sys.path if os.path.isabs(entry) and entry.endswith("site-packages")),
                next(entry for entry in sys.path if os.path.isabs(entry)))
    site_dir = root / site.lstrip("/")
    write(site_dir / "fake_pip_photos-1.0.dist-info/METADATA",
          "Metadata-Version: 2.1\nName: fake-pip-photos\nVersion: 1.0\nLicense: MIT\n")
    room = write(site_dir / "fake_pip_photos/images/room.jpg", image_bytes("JPEG", 14))
    content["fake-pip/room.jpg"] = room.read_bytes()
    manifest = write(tmp_path / "sources.toml", MANIFEST)
    return root, manifest, content


def run(collect, capsys, out, root, manifest, *extra):
    assert collect.main([str(out), "--root", str(root), "--manifest", str(manifest), *extra]) == 0
    return capsys.readouterr()


def copied(out: Path) -> set[str]:
    return {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file() and p.name != "SOURCES.md"}


def test_permissive_photos_are_copied_with_their_names_and_the_rest_never(collect, system, tmp_path, capsys):
    root, manifest, content = system
    out = tmp_path / "photos"
    result = run(collect, capsys, out, root, manifest)
    assert copied(out) == {"fake-photos/Nature/lake.jpg", "fake-photos/Nature/tree.png", "fake-rcc/fish.webp",
                           "fake-rcc/sub/reef.webp", "fake-pip/room.jpg"}
    for name in copied(out):
        assert (out / name).read_bytes() == content[name]
    assert not list(out.rglob("*.tmp")) and not list(out.rglob(".*"))
    # Ground-truth names are refused even though the manifest's glob takes them; each says why.
    assert "im0.png refused" in result.err and "scene_disp.png refused" in result.err
    assert "frame_GT.jpg refused" in result.err
    assert "left01.jpg" not in result.err  # excluded by the manifest: silently
    warnings = [line for line in result.err.splitlines() if "broken.jpg" in line]
    assert len(warnings) == 1 and "not a readable image" in warnings[0]
    assert "mismatch.jpg skipped: the manifest says CC0-1.0, the copyright file GPL-3+" in result.err
    assert "not-there.jpg is not in the installed package" in result.err
    assert "nc.jpg skipped: licence CC-BY-NC-2.0 is neither permissive nor GPL/LGPL" in result.err
    # The install lines for the missing sources the policy admits, and nothing installed.
    assert "apt-get install absent-pkg\n" in result.out
    assert "pip install absent-pip-photos\n" in result.out
    assert "absent-gpl-pkg" not in result.out
    assert "fake-gpl: 0 photographs (1 more with --licences all)" in result.out


def test_gpl_photos_only_with_licences_all_and_gone_again_without(collect, system, tmp_path, capsys):
    root, manifest, content = system
    out = tmp_path / "photos"
    result = run(collect, capsys, out, root, manifest, "--licences", "all")
    assert {"fake-gpl/castle.jpg", "fake-rcc/seal.webp"} <= copied(out)
    assert (out / "fake-rcc/seal.webp").read_bytes() == content["fake-rcc/seal.webp"]
    assert not any(word in name for name in copied(out) for word in ("im0", "disp", "GT", "left", "nc.jpg"))
    assert "apt-get install absent-pkg absent-gpl-pkg\n" in result.out
    assert "GPL-2+" in (out / "SOURCES.md").read_text()
    run(collect, capsys, out, root, manifest)  # back to the permissive default: the GPL photographs go
    assert "fake-gpl/castle.jpg" not in copied(out) and "fake-rcc/seal.webp" not in copied(out)
    assert not (out / "fake-gpl").exists()
    assert "GPL" not in (out / "SOURCES.md").read_text()


def test_sources_md_lists_versions_licences_and_attributions(collect, system, tmp_path, capsys):
    root, manifest, _ = system
    out = tmp_path / "photos"
    run(collect, capsys, out, root, manifest)
    text = (out / "SOURCES.md").read_text()
    assert "| fake-photos | fake-photos (apt) | 1.2-3 | CC-BY-SA-3.0, public-domain | 2 |" in text
    assert "| fake-rcc | fake-rcc (apt) | 0.9-1 | CC-BY-2.0, CC0-1.0 | 2 |" in text
    assert "| fake-pip | fake-pip-photos (pip) | 1.0 | MIT | 1 |" in text
    # Per-file stanzas give per-photo attribution; a wildcard stanza is listed once for its source.
    assert "| Nature/lake.jpg | CC-BY-SA-3.0 | Jane Doe, https://example.org/lake |" in text
    assert "| fish.webp | CC-BY-2.0 | Ann Diver, https://example.org/fish |" in text
    assert "Files: `src/photos/sub/*` - Copyright: Reef Society - License: CC0-1.0" in text
    assert "Licence as the package metadata states it: MIT." in text
    assert "5 photographs from 3 sources." in text


def test_the_collection_is_what_mipnet_photographs_sees(collect, system, tmp_path, capsys, monkeypatch):
    root, manifest, _ = system
    out = tmp_path / "collected"
    run(collect, capsys, out, root, manifest)
    monkeypatch.setenv(photographs.ENV_VARIABLE, str(out))
    seen = set(photographs.names()) | set(photographs.names(held_out=True))
    expected = {f"collected/{name}" for name in copied(out)}
    assert expected <= seen
    assert not any(name.endswith("SOURCES.md") for name in seen)
    assert photographs.load("collected/fake-rcc/fish.webp").size == (40, 30)


def test_rcc_reader_reads_compressed_plain_and_nested_entries(collect):
    files = {"/a/x.webp": b"plain bytes", "/a/b/y.webp": b"zlib bytes" * 10, "/z.png": b"zstd", "/a/b/c/w": b""}
    for version in (1, 2, 3):
        data = make_rcc(files, compressed={"/a/b/y.webp"}, zstd={"/z.png"}, version=version)
        assert collect.read_rcc(data) == {"/a/x.webp": b"plain bytes", "/a/b/y.webp": b"zlib bytes" * 10,
                                          "/z.png": None, "/a/b/c/w": b""}
    with pytest.raises(ValueError, match="not a Qt binary resource"):
        collect.read_rcc(b"PK\x03\x04" + bytes(40))
    with pytest.raises(ValueError, match="corrupt"):
        collect.read_rcc(make_rcc(files)[:40])


def test_an_unreadable_bundle_is_skipped_with_a_warning(collect, system, tmp_path, capsys):
    root, manifest, _ = system
    write(root / "usr/share/fake-rcc/broken.rcc", b"qres" + bytes(12))
    result = run(collect, capsys, tmp_path / "photos", root, manifest)
    assert "broken.rcc: unreadable resource bundle skipped" in result.err
    assert (tmp_path / "photos/fake-rcc/fish.webp").is_file()


@pytest.mark.parametrize("licence, kind", [
    ("public-domain", "permissive"), ("CC0-1.0", "permissive"), ("CC-BY-2.0", "permissive"),
    ("CC-BY-SA-3.0", "permissive"), ("MIT", "permissive"), ("Expat", "permissive"),
    ("Apache-2.0 AND BSD-3-Clause", "permissive"), ("BSD-2-Clause", "permissive"), ("GPL-3+", "copyleft"),
    ("LGPL-2.1+", "copyleft"), ("GPL-2", "copyleft"), ("Expat or GPL-2", "permissive"),
    ("CC-BY-NC-2.0", None), ("CC-BY-ND-3.0", None), ("GFDL-NIV-1.2", None), ("custom", None),
    ("MIT and CC-BY-NC-4.0", None)])
def test_licence_kinds(collect, licence, kind):
    assert collect.licence_kind(licence) == kind


def test_the_shipped_manifest_is_complete_and_names_no_ground_truth(collect):
    sources = collect.load_manifest(collect.MANIFEST)
    assert {s["manager"] for s in sources} == {"apt", "pip"}
    for source in sources:
        assert source["files"], source["name"]
        for group in source["files"]:
            assert collect.licence_kind(group["licence"]) is not None, (source["name"], group["licence"])
            for name in group["include"]:
                assert collect.refused_name(name) is None, name
                assert not any(fnmatch_any(name, ex) for ex in source.get("exclude", [])), name
    opencv = next(s for s in sources if s["package"] == "opencv-doc")
    for name in ("aloe*", "basketball*", "rubberwhale*", "left*", "right*", "graf*", "leuven*"):
        assert name in opencv["exclude"]


def fnmatch_any(name: str, pattern: str) -> bool:
    import fnmatch

    return fnmatch.fnmatchcase(name, pattern) or fnmatch.fnmatchcase(name.rsplit("/", 1)[-1], pattern)
