"""The REALY benchmark (Chai et al., ECCV 2022): region-wise error of predicted face meshes.

:func:`evaluate` gives, for every prediction in a folder, the error (mm) on the four scan regions
nose, mouth, forehead and cheek, with the official REALY code's numbers (github czh-98/REALY,
``main.py``): the rigid alignments bit for bit, and every value within the numerical uncertainty
facegeo reports for it, or 1e-6 relative where that is smaller (synthetic subjects of 36 seeds
and two region sizes, benchmarks/RESULTS.md). Closest points come from one AABB tree (libigl) per prediction
instead of an R-tree per ICP step and per-point queries in Python, with trimesh's tie rule
reproduced; the non-rigid ICP's normal equations are assembled block by block, in METIS'
nested-dissection order, and factored at every step by CHOLMOD as in the official code (through
CVXOPT, the extra ``facegeo[cholmod]``; without it by SciPy's SuperLU, its factor reused within
a stiffness stage by preconditioned conjugate gradients: :mod:`facegeo.eval.realy_solver`). The
regions of all subjects are shared among ``workers`` processes, one BLAS thread each; each
region is computed the same way in any process, so the
numbers do not depend on ``workers``.

Every value comes with its numerical uncertainty (``RealyResult.uncertainty``): how far
round-off can move it. The protocol amplifies round-off: its non-rigid ICP multiplies float32
copies of the deformed vertices by each solution, so any two correct implementations (facegeo
and the official code, or the official code on two BLAS builds) end with vertices that differ by
about a float32 rounding, and that turns the ICP's discrete decisions (nearest targets, the
match threshold, the stopping test) and the final closest points' tie decisions when they are
that close to their thresholds. Each such decision is followed the other way and its effect
counted (:func:`~facegeo.eval.realy_error.region_error`); one turned decision can move a value
by up to 1e-2. Values above ``UNCERTAINTY_FLAG`` (1e-6 relative) are flagged in the summary.
``settings`` (:class:`~facegeo.eval.realy_settings.Settings`) loosens the protocol's stopping rules
and the solver's tolerance for speed; the default is exact.

Per subject (see :mod:`facegeo.eval.realy_align` and :mod:`facegeo.eval.realy_error`):
the 85 keypoints of the prediction from the topology's barycentric keypoint file; a similarity
alignment on 7 of them; a rigid ICP per region; the bidirectional error (non-rigid ICP of the
scan region towards the prediction, then mean distance) times the subject's metrical scale.
The summary is computed, as the official code does, from the values written to
``REALY_error.txt`` (truncated to 9 characters): mean, median, standard deviation (n - 1) per
region, and ``all`` = the mean of the four region means.

Inputs, in the official layout under ``realy_root`` (each path can be given on its own):

* ``data/REALY_HIFI3D_keypoints/<id>.obj``: the 85 keypoints of each scan (``v`` lines);
* ``data/REALY_scan_region/<id>/{nose,mouth,forehead,cheek}.obj``: the scan regions;
* ``data/metrical_scale.txt``: subject ``id`` on line ``id``;
* ``data/<TOPOLOGY>.obj`` + ``data/<TOPOLOGY>.txt``: the prediction topology's template and
  barycentric keypoints. The default topology, ``ICT-FaceKit`` (facegeo's bundled model), falls
  back to the keypoint file bundled with facegeo and the bundled model's triangles.

Predictions are ``PRED_DIR/<name>.obj`` named like the REALY images they come from: ``<id>.obj``
(frontal track) or ``<id>_<view>.obj`` (multi-view track); the subject id is the number before
the first underscore, and subjects are ordered as the official code orders them (by the name's
digits read as one number).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from facegeo.errors import FacegeoError, InputError
from facegeo.eval.realy_align import ERROR_KEYPOINTS, ICP_ORDER, REGIONS, RIGID_KEYPOINTS, global_alignment, regional_icp
from facegeo.eval.realy_error import region_error
from facegeo.eval.realy_geometry import SurfaceQuery
from facegeo.eval.realy_solver import cholmod_available, resolve as resolve_solver
from facegeo.eval.realy_settings import EXACT, Settings
from facegeo.eval.realy_io import (
    Mesh,
    barycentric_points,
    read_keypoint_file,
    read_metrical_scales,
    read_obj,
    read_points_obj,
)

__all__ = [
    "evaluate",
    "evaluate_subject",
    "RealyResult",
    "Settings",
    "EXACT",
    "UNCERTAINTY_FLAG",
    "Topology",
    "load_topology",
    "DEFAULT_TOPOLOGY",
    "REGIONS",
    "format_value",
    "summarize",
]

#: facegeo's default model topology; its keypoint file is bundled (assets/realy/ICT-FaceKit.txt).
DEFAULT_TOPOLOGY = "ICT-FaceKit"

#: A region's numerical uncertainty (relative) above which the summary flags it.
UNCERTAINTY_FLAG = 1e-6

_NAME = re.compile(r"^[0-9]+(_[0-9]+)*$")


@dataclass(frozen=True)
class Topology:
    """A prediction topology: its keypoint rows and (when known) its template triangles."""

    name: str
    keypoint_triangles: np.ndarray  # (85,) triangle index
    keypoint_weights: np.ndarray  # (85, 3) corner weights
    triangles: np.ndarray | None  # (F, 3) template triangles; None: each prediction's own
    n_vertices: int | None  # template vertex count, when known
    source: str  # where the keypoints came from

    def keypoints(self, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
        """The 85 keypoints of a mesh of this topology (float64), as the official code computes them."""
        tris = self.triangles if self.triangles is not None else triangles
        return barycentric_points(vertices, tris, self.keypoint_triangles, self.keypoint_weights)


@dataclass
class RealyResult:
    """What :func:`evaluate` returns.

    ``per_subject``: {name: {region: error in mm}} at full precision, in the official order;
    ``text``: the same values as written to REALY_error.txt (9 characters);
    ``summary``: {region: {"mean", "median", "std"}, "all": mean of the four region means,
    "n": number of predictions}, computed from ``text`` as the official code does;
    ``seconds``: CPU time per subject (reading its files, and its four regions in whichever
    process ran them; CPU time, so that it means the same on a busy machine);
    ``details``: per subject and region, the rigid ICP updates, the non-rigid ICP's ``solver``,
    its solves, symbolic ``analyses``, ``factorisations`` and ``pcg_iterations`` per solve (0 for
    a direct solve), and CPU seconds (``factor_seconds``,
    ``solve_seconds``, ``closest_seconds``, ``nearest_seconds``);
    ``uncertainty``: per subject and region, how far (relative) round-off can move the error
    through the decisions it can turn (see :func:`~facegeo.eval.realy_error.region_error`; the
    ``details`` split it into ``uncertainty_paths`` and ``uncertainty_ties`` and count the
    decisions followed, ``reruns``);
    ``settings``: the knobs used (``solver`` as resolved: ``"cholmod"`` or ``"superlu"``);
    ``wall_seconds``: the whole evaluation (wall clock);
    ``workers``: processes.
    """

    per_subject: dict[str, dict[str, float]]
    text: dict[str, dict[str, str]]
    summary: dict[str, Any]
    topology: str
    seconds: dict[str, float] = field(default_factory=dict)
    details: dict[str, dict[str, Any]] = field(default_factory=dict)
    uncertainty: dict[str, dict[str, float]] = field(default_factory=dict)
    settings: Settings = EXACT
    wall_seconds: float = 0.0
    workers: int = 1

    def uncertain(self, threshold: float = UNCERTAINTY_FLAG) -> list[tuple[str, str, float]]:
        """(name, region, relative uncertainty) of the values whose uncertainty exceeds ``threshold``."""
        return [(name, r, u) for name, values in self.uncertainty.items() for r, u in values.items() if u > threshold]

    def error_txt(self) -> str:
        """REALY_error.txt in the official format: name, an empty field, nose, mouth, forehead, cheek."""
        return "".join(
            name + "\t" + "".join("\t" + self.text[name][r] for r in REGIONS) + "\n" for name in self.per_subject
        )


def format_value(value: float) -> str:
    """A value as the official code writes it: ``str`` of the float64, cut to 9 characters."""
    return repr(float(value))[:9]


def summarize(values: dict[str, dict[str, float]]) -> dict[str, Any]:
    """Mean, median and standard deviation (n - 1) per region, and ``all`` (mean of the means)."""
    summary: dict[str, Any] = {"n": len(values)}
    means = []
    for region in REGIONS:
        data = np.array([v[region] for v in values.values()], dtype=np.float64)
        n = data.shape[0]
        mean = float(data.mean()) if n else math.nan
        std = float(data.std() * np.sqrt(n) / np.sqrt(n - 1)) if n > 1 else math.nan
        summary[region] = {"mean": mean, "median": float(np.median(data)) if n else math.nan, "std": std}
        means.append(mean)
    summary["all"] = float(sum(means) / 4.0)
    return summary


# ------------------------------------------------------------------------------------------ inputs
def _ict_topology() -> Topology:
    from facegeo.assets import asset_path
    from facegeo.model_files import DEFAULT_MODEL_ASSET

    path = asset_path("realy/ICT-FaceKit.txt")
    with np.load(asset_path(DEFAULT_MODEL_ASSET)) as data:
        triangles = np.asarray(data["triangles"], dtype=np.int64)
        n_vertices = int(data["mean_shape"].shape[0])
    tri, weights = read_keypoint_file(path, len(triangles))
    return Topology(DEFAULT_TOPOLOGY, tri, weights, triangles, n_vertices, f"bundled {path.name}")


def load_topology(realy_root: str | Path | None = None, topology: str | None = DEFAULT_TOPOLOGY,
                  keypoints: str | Path | None = None, template: str | Path | None = None) -> Topology:
    """The prediction topology, from ``--topology NAME`` or ``--keypoints FILE`` [``--template OBJ``].

    ``NAME`` reads ``<realy_root>/data/NAME.txt`` and ``NAME.obj``; ``ICT-FaceKit`` falls back to
    the bundled files. A keypoint ``FILE`` takes its triangles from ``template`` or from
    ``FILE`` with the suffix ``.obj`` when that exists, else from each prediction.
    """
    if keypoints is not None:
        kp_path = Path(keypoints)
        obj = Path(template) if template is not None else kp_path.with_suffix(".obj")
        if template is not None or obj.is_file():
            mesh = read_obj(obj, "topology template")
            tri, w = read_keypoint_file(kp_path, len(mesh.triangles))
            return Topology(kp_path.stem, tri, w, mesh.triangles, len(mesh.vertices), str(kp_path))
        tri, w = read_keypoint_file(kp_path)
        return Topology(kp_path.stem, tri, w, None, None, str(kp_path))
    name = topology or DEFAULT_TOPOLOGY
    if "/" in name or "\\" in name or name in (".", ".."):
        raise InputError(name, "topology", "a topology name such as HIFI3D or FLAME (use --keypoints for a file)")
    data = Path(realy_root) / "data" if realy_root is not None else None
    txt = data / f"{name}.txt" if data is not None else None
    obj = data / f"{name}.obj" if data is not None else None
    if txt is not None and txt.is_file():
        if not obj.is_file():
            raise InputError(obj, f"topology {name}", f"the template mesh {name}.obj beside {name}.txt", "missing")
        mesh = read_obj(obj, "topology template")
        tri, w = read_keypoint_file(txt, len(mesh.triangles))
        return Topology(name, tri, w, mesh.triangles, len(mesh.vertices), str(txt))
    if name == DEFAULT_TOPOLOGY:
        return _ict_topology()
    where = txt if txt is not None else Path(f"data/{name}.txt")
    found = "the template mesh but no keypoint file" if obj is not None and obj.is_file() else "no such file"
    raise InputError(where, f"keypoint file of topology {name}",
                     "REALY's 85 barycentric keypoints (data/<TOPOLOGY>.txt, or --keypoints FILE)", found)


@dataclass(frozen=True)
class _Layout:
    keypoints_dir: Path
    regions_dir: Path
    scale_file: Path


def _layout(realy_root: str | Path | None, keypoints_dir, regions_dir, scale_path) -> _Layout:
    data = Path(realy_root) / "data" if realy_root is not None else None

    def pick(given, default_name, what):
        if given is not None:
            return Path(given)
        if data is None:
            raise InputError("<arguments>", what, "--realy-root or an explicit path")
        return data / default_name

    layout = _Layout(
        pick(keypoints_dir, "REALY_HIFI3D_keypoints", "keypoint folder"),
        pick(regions_dir, "REALY_scan_region", "scan region folder"),
        pick(scale_path, "metrical_scale.txt", "metrical scale file"),
    )
    if realy_root is not None and not Path(realy_root).is_dir():
        raise InputError(realy_root, "REALY root", "a folder holding data/ (the official layout)", "no such folder")
    for path, what, hint in (
        (layout.keypoints_dir, "keypoint folder", "data/REALY_HIFI3D_keypoints/<id>.obj"),
        (layout.regions_dir, "scan region folder", "data/REALY_scan_region/<id>/{nose,mouth,forehead,cheek}.obj"),
    ):
        if not path.is_dir():
            raise InputError(path, what, f"a folder ({hint}; unzip REALY's benchmark data into data/)", "no such folder")
    if not layout.scale_file.is_file():
        raise InputError(layout.scale_file, "metrical scale file", "data/metrical_scale.txt", "no such file")
    return layout


def _predictions(pred_dir: str | Path) -> list[tuple[str, int, Path]]:
    folder = Path(pred_dir)
    if not folder.is_dir():
        raise InputError(folder, "prediction folder", "a folder of <id>.obj or <id>_<view>.obj meshes", "no such folder")
    found = [p for p in folder.iterdir() if p.suffix == ".obj" and p.is_file()]
    if not found:
        raise InputError(folder, "prediction folder", "at least one <id>.obj mesh", "no .obj files")
    bad = sorted(p.name for p in found if not _NAME.match(p.stem))
    if bad:
        raise InputError(folder / bad[0], "prediction name",
                         "<id>.obj or <id>_<view>.obj like the REALY image it comes from",
                         f"{len(bad)} such name(s): {', '.join(bad[:5])}")
    items = [(p.stem, int(p.stem.split("_")[0]), p) for p in found]
    items.sort(key=lambda t: (int(t[0].replace("_", "")), t[0]))
    return items


# ------------------------------------------------------------------------------------------ work
@dataclass(frozen=True)
class _Task:
    """One region of one prediction, with its inputs read: the unit of work, whatever the
    number of workers (sent to a worker process by pickling, about 1 MB)."""

    name: str
    region: str
    prepared: "_Prepared"
    region_mesh: Mesh
    topology: Topology
    scale: float
    settings: Settings
    source: str


def _subject_files(layout: _Layout, subject_id: int) -> tuple[Path, dict[str, Path]]:
    kp = layout.keypoints_dir / f"{subject_id}.obj"
    regions = {r: layout.regions_dir / str(subject_id) / f"{r}.obj" for r in REGIONS}
    return kp, regions


@dataclass(frozen=True)
class _Prepared:
    """A prediction after the global alignment: what each of its regions starts from."""

    triangles: np.ndarray  # (F, 3)
    aligned: np.ndarray  # (V, 3) float64, globally aligned vertices
    aligned_keypoints: np.ndarray  # (85, 3) float64
    scan_keypoints: np.ndarray  # (85, 3) float32
    error_triangles: np.ndarray  # (F', 3) triangles of the error step (template mask applied)


def _prepare(prediction: Mesh, scan_keypoints: np.ndarray, topology: Topology, mask: np.ndarray | None,
             source: str) -> _Prepared:
    if topology.n_vertices is not None and len(prediction.vertices) != topology.n_vertices:
        raise InputError(source, "vertices", f"{topology.n_vertices} (the {topology.name} topology)",
                         str(len(prediction.vertices)))
    if topology.triangles is None and topology.keypoint_triangles.max() >= len(prediction.triangles):
        raise InputError(source, "faces", f"more than {int(topology.keypoint_triangles.max())} triangles "
                         "(the keypoint file's largest triangle index)", str(len(prediction.triangles)))
    tris = prediction.triangles
    pred_kp = topology.keypoints(prediction.vertices, tris)
    aligned = global_alignment(prediction.vertices, pred_kp, scan_keypoints)
    error_tris = tris if mask is None else tris[mask[tris].all(axis=1)]
    if len(error_tris) == 0:
        raise InputError(source, "template mask", "a mask that keeps some triangles", "none kept")
    return _Prepared(tris, aligned, topology.keypoints(aligned, tris), scan_keypoints, error_tris)


def _evaluate_region(prepared: _Prepared, region: str, region_mesh: Mesh, topology: Topology,
                     settings: Settings, source: str) -> tuple[float, dict[str, Any]]:
    """One region's error (scan units) and details: the same computation in any process.

    Each region gets its own closest-point trees, so that its numbers do not depend on which
    regions ran before it in the same process (``workers`` changes nothing).
    """
    tris = prepared.triangles
    surface = SurfaceQuery(tris)
    idx = list(RIGID_KEYPOINTS[region])
    try:
        vertices, updates = regional_icp(prepared.aligned, surface, region_mesh.vertices,
                                         prepared.aligned_keypoints[idx], prepared.scan_keypoints[idx], region,
                                         settings)
    except ValueError as exc:
        raise InputError(source, f"{region} region", "more vertices than keypoints", str(exc)) from None
    subset = ERROR_KEYPOINTS[region]
    if subset is None:
        kp, scan_kp = None, None
    else:
        kp = topology.keypoints(vertices, tris)[list(subset)]
        scan_kp = prepared.scan_keypoints[list(subset)]
    error_surface = surface if prepared.error_triangles is tris else SurfaceQuery(prepared.error_triangles)
    try:
        value, info = region_error(vertices, error_surface, region_mesh.vertices, region_mesh.triangles, kp,
                                   scan_kp, settings)
    except FacegeoError as exc:
        raise FacegeoError(f"{source}: {region}: {exc}") from None
    info["closest_seconds"] = surface.seconds + (error_surface.seconds if error_surface is not surface else 0.0)
    return value, {"icp_updates": updates, **info}


def evaluate_subject(prediction: Mesh, scan_keypoints: np.ndarray, regions: dict[str, Mesh],
                     topology: Topology, scale: float = 1.0, mask: np.ndarray | None = None,
                     source: str = "<prediction>", settings: Settings = EXACT,
                     ) -> tuple[dict[str, float], dict[str, Any]]:
    """Errors (mm) of one prediction against one scan: {region: value}, and per-region details."""
    prepared = _prepare(prediction, scan_keypoints, topology, mask, source)
    errors: dict[str, float] = {}
    details: dict[str, Any] = {}
    for region in REGIONS:
        value, details[region] = _evaluate_region(prepared, region, regions[region], topology, settings, source)
        errors[region] = value * scale
    return errors, details


def _run(task: _Task) -> tuple[str, str, Any, Any, float]:
    """(name, region, error in mm or None, details or the error's payload, seconds)."""
    start = time.process_time()
    try:
        value, details = _evaluate_region(task.prepared, task.region, task.region_mesh, task.topology,
                                          task.settings, task.source)
    except InputError as exc:  # re-raised in the parent (InputError's own pickling loses fields)
        failure = ("input", (exc.source, exc.field, exc.expected, exc.found))
        return task.name, task.region, None, failure, time.process_time() - start
    except FacegeoError as exc:
        return task.name, task.region, None, ("other", str(exc)), time.process_time() - start
    return task.name, task.region, value * task.scale, details, time.process_time() - start


def _read_mask(path: str | Path | np.ndarray | None, n_vertices: int | None) -> np.ndarray | None:
    if path is None:
        return None
    if isinstance(path, np.ndarray):
        mask = path.reshape(-1)
        source = "<array>"
    else:
        source = str(path)
        try:
            mask = np.loadtxt(path, delimiter=",", dtype=np.int32).reshape(-1)
        except (OSError, ValueError) as exc:
            raise InputError(path, "template mask", "comma-separated 0/1 values, one per vertex", type(exc).__name__) from None
    if n_vertices is not None and mask.size != n_vertices:
        raise InputError(source, "template mask", f"{n_vertices} values (one per vertex)", str(mask.size))
    return mask != 0


def evaluate(
    pred_dir: str | Path,
    realy_root: str | Path | None = None,
    topology: str | None = DEFAULT_TOPOLOGY,
    keypoints: str | Path | None = None,
    workers: int = 1,
    *,
    template: str | Path | None = None,
    keypoints_dir: str | Path | None = None,
    regions_dir: str | Path | None = None,
    scale_path: str | Path | None = None,
    template_mask: str | Path | np.ndarray | None = None,
    settings: Settings = EXACT,
    progress: bool | None = False,
    client: Any = None,
) -> RealyResult:
    """Evaluate every ``PRED_DIR/*.obj`` with the REALY protocol (see the module doc).

    ``topology`` names the prediction topology (``data/<NAME>.{obj,txt}``; default: facegeo's
    ICT-FaceKit); ``keypoints`` gives a barycentric keypoint file instead (triangles from
    ``template`` or the ``.obj`` beside it). ``workers`` > 1 evaluates the regions of all
    subjects in that many processes (the numbers do not depend on it). ``template_mask``: the
    official ``--template_mask`` (0/1 per vertex, comma separated; only triangles whose three
    vertices are 1 are used in the error step). ``settings``: the speed / exactness knobs
    (:class:`~facegeo.eval.realy_settings.Settings`; the default is the official protocol).
    ``progress``: a tqdm bar (None: only on a terminal). ``client``: a
    :class:`distributed.Client`; the regions are then evaluated on its cluster's workers instead
    (``workers`` is ignored; the same numbers: each region is the same computation anywhere).

    Raises:
        InputError: a wrong folder layout, a missing subject file, a prediction with a wrong
            vertex count, NaN coordinates, a topology without a keypoint file, ...
        FacegeoError: a subject whose computation failed (the message names it).
    """
    start = time.perf_counter()
    # "auto" becomes the backend here, so that every worker uses the same and the result names it
    settings = dataclasses.replace(settings, solver=resolve_solver(settings.solver))
    layout = _layout(realy_root, keypoints_dir, regions_dir, scale_path)
    topo = load_topology(realy_root, topology, keypoints, template)
    mask = _read_mask(template_mask, topo.n_vertices)
    scales = read_metrical_scales(layout.scale_file)
    items = _predictions(pred_dir)
    for name, subject_id, path in items:
        if not 1 <= subject_id <= len(scales):
            raise InputError(path, "subject id", f"1..{len(scales)} (the lines of {layout.scale_file.name})", str(subject_id))
        kp_path, region_paths = _subject_files(layout, subject_id)
        for p in (kp_path, *region_paths.values()):
            if not p.is_file():
                raise InputError(p, f"REALY data of subject {subject_id} (for {path.name})", "an existing file", "missing")
    # every input is read and checked here first (a bad file fails at once, in the official order)
    tasks = []
    read_seconds: dict[str, float] = {}
    for name, subject_id, path in items:
        begin = time.process_time()
        kp_path, region_paths = _subject_files(layout, subject_id)
        prediction = read_obj(path, "prediction")
        scan_keypoints = read_points_obj(kp_path, "REALY keypoints", count=85)
        regions = {r: read_obj(region_paths[r], f"{r} region") for r in ICP_ORDER}
        prepared = _prepare(prediction, scan_keypoints, topo, mask, str(path))
        for region in ICP_ORDER:
            tasks.append(_Task(name, region, prepared, regions[region], topo, float(scales[subject_id - 1]),
                               settings, str(path)))
        read_seconds[name] = time.process_time() - begin
    # largest regions first, so that the last ones to finish are short (the order changes no number)
    tasks.sort(key=lambda t: -len(t.region_mesh.vertices))

    results: dict[tuple[str, str], tuple[float, dict, float]] = {}
    bar = _progress_bar(len(tasks), progress)
    if workers > 1 and len(tasks) > 1 and topo.triangles is not None:
        SurfaceQuery(topo.triangles).rings()  # once here, inherited by the forked workers
    try:
        if client is not None:
            from distributed import as_completed as dask_completed

            futures = [client.submit(_run, t, pure=False) for t in tasks]  # one small graph each (≈1 MB), not one huge one
            try:
                for fut in dask_completed(futures):
                    _collect(results, fut.result())
                    bar.update(1)
            except BaseException:
                client.cancel(futures)
                raise
        elif workers <= 1 or len(tasks) == 1:
            for task in tasks:
                _collect(results, _run(task))
                bar.update(1)
        else:
            with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=_context(),
                                     initializer=_one_blas_thread) as pool:
                futures = [pool.submit(_run, t) for t in tasks]
                try:
                    for fut in as_completed(futures):
                        _collect(results, fut.result())
                        bar.update(1)
                except BaseException:
                    for fut in futures:
                        fut.cancel()
                    raise
    finally:
        bar.close()

    per_subject = {name: {r: results[name, r][0] for r in REGIONS} for name, _, _ in items}
    text = {name: {r: format_value(v[r]) for r in REGIONS} for name, v in per_subject.items()}
    summary = summarize({name: {r: float(t[r]) for r in REGIONS} for name, t in text.items()})
    return RealyResult(
        per_subject=per_subject,
        text=text,
        summary=summary,
        topology=topo.name,
        seconds={name: read_seconds[name] + sum(results[name, r][2] for r in REGIONS) for name in per_subject},
        details={name: {r: results[name, r][1] for r in REGIONS} for name in per_subject},
        uncertainty={name: {r: results[name, r][1]["uncertainty"] for r in REGIONS} for name in per_subject},
        settings=settings,
        wall_seconds=time.perf_counter() - start,
        workers=len(client.scheduler_info()["workers"]) if client is not None else workers,
    )


def _collect(results: dict, outcome: tuple[str, str, Any, Any, float]) -> None:
    name, region, value, details, seconds = outcome
    if value is None:
        kind, payload = details
        raise InputError(*payload) if kind == "input" else FacegeoError(payload)
    results[name, region] = (value, details, seconds)



def _context():
    import multiprocessing as mp

    # fork: the workers inherit the imported modules (no re-import per worker)
    return mp.get_context("fork") if "fork" in mp.get_all_start_methods() and os.name == "posix" else None


def _one_blas_thread() -> None:
    """Worker set-up: one BLAS thread per process (SuperLU and CHOLMOD call BLAS; with N workers,
    N times the default thread count oversubscribes the cores: 2 workers ran at 1.4 s per subject
    instead of 0.9 s). CVXOPT, when installed, is imported first so that its own BLAS is limited too."""
    from threadpoolctl import threadpool_limits

    cholmod_available()
    threadpool_limits(1)


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(total: int, progress: bool | None):
    if progress is False:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, unit="subject", desc="REALY", disable=None if progress is None else False)
