"""The learned regressor (facegeo.regressor) with tiny networks on synthetic renders of the model."""

import csv
import dataclasses
import functools
import json

import numpy as np
import pytest
import torch

pytest.importorskip("transformers")

from facegeo import Camera, project  # noqa: E402
from facegeo.assets import asset_path  # noqa: E402
from facegeo.camera import rotation_from_euler  # noqa: E402
from facegeo.cli import main  # noqa: E402
from facegeo.errors import InputError  # noqa: E402
from facegeo.fitting import Fit  # noqa: E402
from facegeo.fitting.landmark_problem import LandmarkProblem  # noqa: E402
from facegeo.landmarks.scheme import LANDMARK_WEIGHTS, landmark_loss  # noqa: E402
from facegeo.lighting import AMBIENT_WHITE  # noqa: E402
from facegeo.morphable_model import MorphableModel  # noqa: E402
from facegeo.regressor import (  # noqa: E402
    MSSFRegressor,
    ModelSignature,
    Objective,
    RegressorConfig,
    evaluate,
    load,
    make_synthetic_faces,
    save_checkpoint,
    train,
)
from facegeo.regressor.data import FaceCrops, Sample, crop_box, crop_face, landmark_table, list_images  # noqa: E402
from facegeo.regressor.synthetic import random_face, render_face  # noqa: E402
from facegeo.regressor.losses import slide_jaw  # noqa: E402
from test_fitting import similarity_rms  # noqa: E402  (the project's one 3D error)

TINY = {
    "network": {"image_size": 32, "width": 16,
                "convnext": {"hidden_sizes": [8, 8, 16, 16], "depths": [1, 1, 1, 1]},
                "dino": {"hidden_size": 16, "num_hidden_layers": 2, "num_attention_heads": 2, "intermediate_size": 32}},
    "loss": {"pho": 0.0},
    "train": {"lr": 1e-3, "batch_size": 2, "epochs": 2, "val_fraction": 0.0, "checkpoint_every": 0, "augment": True},
}


def tiny_config(**train) -> RegressorConfig:
    data = json.loads(json.dumps(TINY))
    data["train"].update(train)
    return RegressorConfig.from_dict(data)


@pytest.fixture(scope="module")
def faces(model, tmp_path_factory):
    """Six synthetic renders (96 px) with their ground truth."""
    folder = make_synthetic_faces(tmp_path_factory.mktemp("faces") / "synthetic", 6, model, size=96, seed=3)
    return folder, dict(np.load(folder / "faces.npz"))


def small_model(model: MorphableModel) -> MorphableModel:
    """Another model layout: fewer components, unbounded expressions, two texture components."""
    return MorphableModel(model.mean_shape, model.id_basis[:7], model.exp_basis[:4], model.mean_albedo,
                          0.05 * model.id_basis[:2], model.triangles, model.uv, model.uv_triangles,
                          model.landmark_indices, model.face_mask, name="other")


def test_truth_has_zero_landmark_loss_in_the_crop(model, faces):
    """Crop cameras, projection and jaw sliding agree with the renderer's ground truth."""
    folder, truth = faces
    table, skipped = landmark_table(list_images(folder), folder / "unused.npz", "truth", 1024, progress=False)
    assert not skipped
    crops = FaceCrops([table[n] for n in truth["names"]], 64, 1.5, augment=False)
    batch = {k: torch.stack([crops[i][k] for i in range(len(crops))]) for k in ("image", "intrinsics", "landmarks")}
    params = {k: torch.from_numpy(truth[k]) for k in ("alpha", "delta", "beta", "gamma", "rotation", "translation")}
    config = tiny_config().loss
    config.pho = 1.0
    objective = Objective(model, config, 64)
    terms = objective(params, batch["image"], batch["intrinsics"], batch["landmarks"])
    assert float(terms["lan"].max()) < 1e-8
    # the landmark-only path (subset of vertices) gives the same landmark loss as the full one
    moved = dict(params, alpha=params["alpha"] + 0.3)
    config.pho = 0.0
    subset = Objective(model, config, 64)(moved, batch["image"], batch["intrinsics"], batch["landmarks"])["lan"]
    full = objective(moved, batch["image"], batch["intrinsics"], batch["landmarks"])["lan"]
    torch.testing.assert_close(subset, full, rtol=1e-4, atol=1e-7)
    assert (full > 1e-5).all()


def test_prior_is_the_map_fits_prior_at_the_networks_landmark_noise(model, faces):
    """L_reg = σ²/Σw · (‖α‖² + Σ(δ/s_δ)² + 2/τ·Σ|δ|) with σ² = mean L_lan / 2 (no gradient), the
    noise floor when the landmarks are exact; the PCA model's δ gets N(0, I)."""
    from facegeo.fitting import DEFAULT_PRIORS as P

    folder, truth = faces
    table, _ = landmark_table(list_images(folder), folder / "unused.npz", "truth", 1024, progress=False)
    crops = FaceCrops([table[n] for n in truth["names"]], 64, 1.5, augment=False)
    batch = {k: torch.stack([crops[i][k] for i in range(len(crops))]) for k in ("image", "intrinsics", "landmarks")}
    params = {k: torch.from_numpy(truth[k]) for k in ("alpha", "delta", "beta", "gamma", "rotation", "translation")}
    params["gamma"] = torch.zeros_like(params["gamma"]) + torch.tensor(AMBIENT_WHITE)  # no SH term
    config = tiny_config().loss
    objective = Objective(model, config, 64)
    exact = objective(params, batch["image"], batch["intrinsics"], batch["landmarks"])
    a, d = params["alpha"].double(), params["delta"].double()
    prior = (a * a).sum(-1) + (d / P.expression_scale).pow(2).sum(-1) + 2 * P.expression_rate * d.abs().sum(-1)
    weight_sum = float(LANDMARK_WEIGHTS.sum())
    torch.testing.assert_close(exact["reg"].double(), P.noise_floor**2 / weight_sum * prior, rtol=1e-5, atol=0)
    moved = dict(params, alpha=params["alpha"] + 0.5)
    terms = objective(moved, batch["image"], batch["intrinsics"], batch["landmarks"])
    noise2 = float(terms["lan"].mean()) / 2
    assert noise2 > P.noise_floor**2
    a = moved["alpha"].double()
    prior = (a * a).sum(-1) + (d / P.expression_scale).pow(2).sum(-1) + 2 * P.expression_rate * d.abs().sum(-1)
    torch.testing.assert_close(terms["reg"].double(), noise2 / weight_sum * prior, rtol=1e-5, atol=0)
    # a PCA expression model: δ ~ N(0, I), no L1 term
    other = small_model(model)
    p2 = {"alpha": torch.ones(2, other.n_id), "delta": torch.full((2, other.n_exp), -2.0), "beta": torch.zeros(2, other.n_tex),
          "gamma": params["gamma"][:2], "rotation": params["rotation"][:2], "translation": params["translation"][:2]}
    t2 = Objective(other, dataclasses.replace(config, reg_tex=0.0), 64)(p2, batch["image"][:2], batch["intrinsics"][:2],
                                                                         batch["landmarks"][:2])
    expected = (t2["lan"].mean() / 2).clamp_min(P.noise_floor**2) / weight_sum * (other.n_id + 4.0 * other.n_exp)
    torch.testing.assert_close(t2["reg"], expected.expand(2), rtol=1e-5, atol=0)


def test_expression_output_is_projected_with_a_straight_through_gradient(model):
    """δ = the head's output clipped into [0, 1] (ICT); the gradient reaches an output outside
    the range (a sigmoid's would vanish at δ = 0), and delta_free is the unclipped output."""
    net = MSSFRegressor(tiny_config().network, ModelSignature.of(model))
    n = ModelSignature.of(model).n_outputs
    raw = torch.zeros(1, n)
    e0 = model.n_id
    raw[0, e0:e0 + 3] = torch.tensor([-0.3, 0.4, 1.7])
    raw.requires_grad_(True)
    p = net.decode(raw, torch.tensor([[80.0, 16.0, 16.0]]))
    torch.testing.assert_close(p["delta"][0, :3].detach(), torch.tensor([0.0, 0.4, 1.0]))
    torch.testing.assert_close(p["delta_free"][0, :3].detach(), torch.tensor([-0.3, 0.4, 1.7]))
    assert float(p["delta"].detach().min()) >= 0 and float(p["delta"].detach().max()) <= 1
    weights = torch.arange(1.0, model.n_exp + 1)
    (p["delta"] * weights).sum().backward()
    torch.testing.assert_close(raw.grad[0, e0:e0 + model.n_exp], weights)


def test_photometric_loss_is_small_at_the_truth(model):
    """A face rendered with the model's own albedo: L_pho at the true parameters is the
    resampling error only; wrong lighting or a shifted pose costs more."""
    rng = np.random.default_rng(2)
    face = random_face(model, rng, 256, max_yaw=30)
    face["albedo"] = model.mean_albedo
    image, landmarks, camera = render_face(model, face, 256, rng)
    sample = Sample("<memory>", landmarks, camera)
    x0, y0, side = crop_box(landmarks.astype(np.float64), 1.5)
    crop = crop_face(image, (x0, y0, side), 128).astype(np.float32) / 255
    s = 128 / side
    intrinsics = torch.tensor([[camera.focal * s, (camera.cx - x0) * s, (camera.cy - y0) * s]])
    lm = torch.from_numpy((sample.landmarks - [x0, y0]) * s).float()[None]
    img = torch.from_numpy(crop.transpose(2, 0, 1))[None]
    config = tiny_config().loss
    config.pho = 1.0
    objective = Objective(model, config, 128)
    params = {k: torch.from_numpy(np.asarray(face[k]))[None] for k in ("alpha", "delta", "beta", "gamma", "rotation", "translation")}
    at_truth = float(objective(params, img, intrinsics, lm)["pho"])
    darker = float(objective(dict(params, gamma=params["gamma"] * 0.6), img, intrinsics, lm)["pho"])
    shifted = float(objective(dict(params, translation=params["translation"] + torch.tensor([8.0, 0, 0])), img, intrinsics, lm)["pho"])
    assert at_truth < 0.03 and darker > 3 * at_truth and shifted > 1.5 * at_truth, (at_truth, darker, shifted)


def test_perceptual_loss_from_a_local_torchscript_network(model, tmp_path):
    class Embed(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.conv = torch.nn.Conv2d(3, 8, 3, stride=2)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return torch.relu(self.conv(x)).mean(dim=(2, 3))

    torch.manual_seed(0)
    torch.jit.script(Embed()).save(str(tmp_path / "embed.pt"))
    rng = np.random.default_rng(4)
    face = random_face(model, rng, 128, max_yaw=20)
    image, landmarks, camera = render_face(model, face, 128, rng)
    x0, y0, side = crop_box(landmarks.astype(np.float64), 1.5)
    img = torch.from_numpy(crop_face(image, (x0, y0, side), 64).astype(np.float32).transpose(2, 0, 1) / 255)[None]
    s = 64 / side
    intrinsics = torch.tensor([[camera.focal * s, (camera.cx - x0) * s, (camera.cy - y0) * s]])
    lm = torch.from_numpy((landmarks - [x0, y0]) * s).float()[None]
    config = tiny_config().loss
    config.per, config.perceptual_checkpoint = 1.0, str(tmp_path / "embed.pt")
    params = {k: torch.from_numpy(np.asarray(face[k]))[None] for k in ("alpha", "delta", "beta", "gamma", "rotation", "translation")}
    params["gamma"] = (params["gamma"] * 3).requires_grad_()  # far too bright: the composite differs
    per = Objective(model, config, 64)(params, img, intrinsics, lm)["per"]
    assert 0 < float(per) <= 2
    per.sum().backward()
    assert float(params["gamma"].grad.abs().sum()) > 0
    (tmp_path / "bad.pt").write_bytes(b"nope")
    config.perceptual_checkpoint = str(tmp_path / "bad.pt")
    with pytest.raises(InputError, match="bad.pt: perceptual_checkpoint"):
        Objective(model, config, 64)


def test_jaw_sliding_matches_fit_landmarks(model):
    rng = np.random.default_rng(5)
    camera = Camera.for_image(400, 400)
    alpha = torch.from_numpy(rng.normal(0, 0.7, model.n_id).astype(np.float32))
    rotation = torch.from_numpy(rotation_from_euler(40.0, 5.0, -3.0)).float()
    translation = torch.tensor([5.0, -8.0, -650.0])
    points = model.shape(alpha)
    targets = project(points[model.landmark_indices], rotation, translation, camera) + torch.from_numpy(rng.normal(0, 6, (88, 2))).float()
    problem = LandmarkProblem(model, targets.double().numpy(), camera, LANDMARK_WEIGHTS)
    zero_exp = np.zeros(model.n_exp)
    r64, t64, a64 = rotation.double().numpy(), translation.double().numpy(), alpha.double().numpy()
    problem.slide_jaw(r64, t64, a64, zero_exp)
    expected = torch.from_numpy(problem.projected(r64, t64, a64, zero_exp))
    got = slide_jaw((points @ rotation.T + translation)[None], model.landmark_indices, targets[None], camera)[0]
    torch.testing.assert_close(got.double(), expected, atol=2e-3, rtol=0)
    frontal = project(points[model.landmark_indices[:8]], rotation, translation, camera)
    assert (got[:8] - frontal).norm(dim=1).max() > 1.0  # the jaw did slide


def test_batched_landmark_loss_equals_one_at_a_time():
    rng = np.random.default_rng(0)
    pred = torch.from_numpy(rng.normal(0, 5, (3, 88, 2)))
    target = torch.from_numpy(rng.normal(0, 5, (3, 88, 2)))
    target[1, 10] = float("nan")
    scale = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    batched = landmark_loss(pred, target, scale=scale)
    single = torch.stack([landmark_loss(pred[i], target[i], scale=float(scale[i])) for i in range(3)])
    torch.testing.assert_close(batched, single)


@pytest.mark.parametrize("which", ["ict", "other"])
def test_head_sizes_and_start_come_from_the_model(model, which):
    m = model if which == "ict" else small_model(model)
    config = tiny_config().network
    net = MSSFRegressor(config, ModelSignature.of(m))
    assert net.head[-1].out_features == m.n_id + m.n_exp + m.n_tex + 27 + 6
    intrinsics = torch.tensor([[80.0, 10.0, 20.0]])
    p = net.predict(torch.rand(1, 3, 32, 32), intrinsics)
    assert p["alpha"].shape == (1, m.n_id) and p["beta"].shape == (1, m.n_tex) and p["gamma"].shape == (1, 3, 9)
    assert torch.count_nonzero(p["alpha"]) == 0
    torch.testing.assert_close(p["rotation"][0], torch.eye(3))
    assert torch.count_nonzero(p["delta"]) == 0  # the mean face: δ = 0 (ICT's lower bound, or unbounded)
    # the mean landmark centroid starts at the crop centre, whatever the principal point
    anchor = torch.tensor(ModelSignature.of(m).anchor)
    cam = Camera(80.0, 10.0, 20.0, 32, 32)
    uv = project(anchor[None], p["rotation"][0], p["translation"][0], cam)
    torch.testing.assert_close(uv[0], torch.tensor([16.0, 16.0]), atol=1e-4, rtol=0)


def test_backbones_load_from_local_folders(model, tmp_path, monkeypatch):
    from transformers import ConvNextV2Config, ConvNextV2Model, DINOv3ViTConfig, DINOv3ViTModel

    net = TINY["network"]
    ConvNextV2Model(ConvNextV2Config(**net["convnext"])).save_pretrained(tmp_path / "convnext")
    dino = DINOv3ViTModel(DINOv3ViTConfig(num_register_tokens=4, **net["dino"]))
    dino.save_pretrained(tmp_path / "dino")
    config = tiny_config().network
    config.convnext_weights = str(tmp_path / "convnext")
    monkeypatch.setenv("FACEGEO_DINOV3_WEIGHTS", str(tmp_path / "dino"))
    loaded = MSSFRegressor(config, ModelSignature.of(model))
    assert loaded.loaded == {"convnext": str(tmp_path / "convnext"), "dino": str(tmp_path / "dino")}
    for k, v in dino.state_dict().items():
        assert torch.equal(loaded.dino.state_dict()[k], v)
    config.convnext_weights = str(tmp_path / "missing")
    with pytest.raises(InputError, match="missing.*config.json"):
        MSSFRegressor(config, ModelSignature.of(model))


def test_frozen_dino_gets_no_gradient_and_does_not_change(model, faces, tmp_path):
    folder, _ = faces
    config = tiny_config(epochs=1)
    train(folder, tmp_path / "run", config, model=model, progress=False, max_steps=1)
    net = load(tmp_path / "run" / "last.pt", model=model).network
    dino_before = {k: v.clone() for k, v in net.dino.state_dict().items()}
    convnext_before = {k: v.clone() for k, v in net.convnext.state_dict().items()}
    summary = train(folder, tmp_path / "run", config, model=model, progress=False, max_steps=3)
    assert summary["steps"] == 3
    trained = load(tmp_path / "run" / "last.pt", model=model).network
    assert all(torch.equal(dino_before[k], v) for k, v in trained.dino.state_dict().items())
    assert not all(torch.equal(convnext_before[k], v) for k, v in trained.convnext.state_dict().items())
    assert all(not p.requires_grad for p in trained.dino.parameters())
    # a backward pass leaves the DINOv3 without gradients
    trained.train()
    assert not trained.dino.training
    trained(torch.rand(2, 3, 32, 32)).sum().backward()
    assert all(p.grad is None for p in trained.dino.parameters())
    assert any(p.grad is not None for p in trained.convnext.parameters())


def test_checkpoint_round_trip_and_bad_checkpoints(model, faces, tmp_path):
    folder, truth = faces
    config = tiny_config()
    net = MSSFRegressor(config.network, ModelSignature.of(model))
    torch.nn.init.normal_(net.head[-1].weight, std=0.01)  # a non-trivial head
    path = save_checkpoint(tmp_path / "net.pt", net, config)
    predictor = load(path, model=model)
    x = torch.rand(2, 3, 32, 32)
    with torch.no_grad():
        assert torch.equal(net.eval()(x), predictor.network(x))
    # the predictor returns a Fit in the photo's camera
    from facegeo import load_photo

    photo = load_photo(folder / str(truth["names"][0]))
    result = predictor(photo, landmarks=truth["landmarks"][0])
    assert isinstance(result, Fit) and result.info["fitter"] == "regressor"
    assert result.vertices.shape == (model.n_vertices, 3) and np.isfinite(result.vertices).all()
    np.testing.assert_allclose(result.vertices, result.shape_vertices @ result.rotation.T + result.translation, atol=1e-3)
    assert np.isfinite(result.landmark_rms_px)
    # missing, truncated, foreign, mismatched: one InputError naming the file
    with pytest.raises(InputError, match="nothere.pt"):
        load(tmp_path / "nothere.pt", model=model)
    cut = tmp_path / "cut.pt"
    cut.write_bytes(path.read_bytes()[:5000])
    with pytest.raises(InputError, match="cut.pt"):
        load(cut, model=model)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(InputError, match="foreign.pt.*format"):
        load(foreign, model=model)
    with pytest.raises(InputError, match=r"net.pt: signature.n_id: expected 7"):
        load(path, model=small_model(model))


def test_resume_continues_the_same_loss_curve(model, faces, tmp_path):
    folder, _ = faces
    config = tiny_config(epochs=2, batch_size=2)

    def losses(run):
        with open(run / "metrics.csv") as f:
            return [(int(r["step"]), float(r["total"])) for r in csv.DictReader(f) if r["split"] == "train"]

    train(folder, tmp_path / "once", config, model=model, progress=False)
    train(folder, tmp_path / "twice", config, model=model, progress=False, max_steps=4)  # stops mid-epoch 2
    summary = train(folder, tmp_path / "twice", config, model=model, progress=False)
    assert summary["steps"] == 6
    once, twice = losses(tmp_path / "once"), losses(tmp_path / "twice")
    assert [s for s, _ in twice] == list(range(1, 7))
    np.testing.assert_allclose([v for _, v in twice], [v for _, v in once], rtol=1e-5)


def test_bad_images_are_skipped_and_listed(model, faces, tmp_path):
    folder, _ = faces
    import shutil

    copy = tmp_path / "images"
    shutil.copytree(folder, copy)
    (copy / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    (copy / "zzz.png").write_bytes((copy / "000000.png").read_bytes())  # no ground truth for it
    table, skipped = landmark_table(list_images(copy), tmp_path / "lm.npz", "truth", 1024, progress=False)
    assert len(table) == 6
    assert [name for name, _ in skipped] == ["broken.png", "zzz.png"]


def test_cli_regressor_options_and_errors(model, tmp_path, capsys):
    photo = asset_path("photos/astronaut.png")
    assert main(["fit", str(photo), "-o", str(tmp_path / "a"), "--regressor", str(tmp_path / "none.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.pt" in err[0]
    assert main(["fit", str(photo), "-o", str(tmp_path / "b"), "--refine"]) == 2
    assert "--regressor" in capsys.readouterr().err
    config = tiny_config()
    ckpt = save_checkpoint(tmp_path / "net.pt", MSSFRegressor(config.network, ModelSignature.of(model)), config)
    assert main(["fit", str(photo), "-o", str(tmp_path / "c"), "--regressor", str(ckpt), "--no-photometric"]) == 0
    record = json.loads((tmp_path / "c" / "fit.json").read_text())
    assert record["info"]["fitter"] == "regressor" and len(record["alpha"]) == model.n_id
    assert main(["fit", str(photo), "-o", str(tmp_path / "d"), "--regressor", str(ckpt), "--refine", "--no-photometric"]) == 0
    record = json.loads((tmp_path / "d" / "fit.json").read_text())
    assert record["info"]["fitter"] == "regressor+refine" and record["landmark_rms_px"] < 5.0


def test_train_regressor_command(faces, tmp_path, capsys):
    folder, _ = faces
    (tmp_path / "tiny.json").write_text(json.dumps(TINY))
    args = ["train-regressor", "--images", str(folder), "--out", str(tmp_path / "run"), "--config", str(tmp_path / "tiny.json"),
            "--max-steps", "1"]
    assert main(args) == 0
    assert "trained 1 steps" in capsys.readouterr().out
    assert {"last.pt", "best.pt", "metrics.csv", "config.json", "skipped.txt"} <= {p.name for p in (tmp_path / "run").iterdir()}
    (tmp_path / "bad.json").write_text(json.dumps({"loss": {"lambda_lan": 1.0}}))
    assert main(["train-regressor", "--images", str(folder), "--out", str(tmp_path / "r2"), "--config", str(tmp_path / "bad.json")]) == 2
    err = capsys.readouterr().err
    assert "bad.json: config.loss" in err and "lambda_lan" in err


def test_make_synthetic_faces_command(tmp_path, capsys):
    assert main(["make-synthetic-faces", "--out", str(tmp_path / "s"), "--count", "2", "--size", "64"]) == 0
    truth = np.load(tmp_path / "s" / "faces.npz")
    assert truth["landmarks"].shape == (2, 88, 2) and sorted(p.name for p in (tmp_path / "s").glob("*.png")) == ["000000.png", "000001.png"]
    assert main(["make-synthetic-faces", "--out", str(tmp_path / "t"), "--count", "0"]) == 2


def test_pipeline_fitter_seam(model, faces):
    from facegeo.pipeline import reconstruct_with_fit

    folder, truth = faces
    config = tiny_config()
    net = MSSFRegressor(config.network, ModelSignature.of(model))
    from facegeo.regressor import Predictor

    fitter = functools.partial(Predictor(net, model, config), landmarks=truth["landmarks"][1])
    asset, result = reconstruct_with_fit(folder / str(truth["names"][1]), model, size=64, maps=("albedo",), fitter=fitter)
    assert result.info["fitter"] == "regressor"
    np.testing.assert_allclose(asset.metadata["fit"]["alpha"], result.alpha)


def _camera_case(model, faces):
    """(photo, landmarks (88, 2) px, predictor, refining predictor): one 96 px synthetic render and
    an untrained tiny network (seeded), once plain and once with ``refine``."""
    from facegeo import load_photo
    from facegeo.regressor import Predictor

    folder, truth = faces
    config = tiny_config()
    with torch.random.fork_rng():
        torch.manual_seed(0)
        net = MSSFRegressor(config.network, ModelSignature.of(model))
    return (load_photo(folder / str(truth["names"][2])), truth["landmarks"][2], Predictor(net, model, config),
            Predictor(net, model, config, refine=True))


def test_an_unknown_focal_is_predicted_with_the_fits_estimate(model, faces):
    """Issue 47: a photo of unknown lens is predicted in the camera the fit estimates from the same
    landmarks, not in the 40° placeholder, and the Fit reports it with the fit's note."""
    from facegeo import fit

    photo, landmarks, predictor, _ = _camera_case(model, faces)
    unknown = Camera.unknown_focal(96, 96)
    fitted = fit(photo, model=model, landmarks=landmarks, camera=unknown, photometric=False)
    assert fitted.camera.focal != pytest.approx(unknown.focal, rel=0.05)  # the estimate is not the placeholder
    predicted = predictor(photo, landmarks=landmarks, camera=unknown)
    assert predicted.camera == fitted.camera and not predicted.camera.focal_known
    estimate_note = [n for n in fitted.info["notes"] if n.startswith("focal length unknown")]
    assert len(estimate_note) == 1 and estimate_note[0] in predicted.info["notes"]
    inner = predicted.landmark_vertices[17:]  # the jaw's fitted points slide between vertices
    uv = project(predicted.shape_vertices[inner], predicted.rotation, predicted.translation, fitted.camera)
    np.testing.assert_allclose(uv, predicted.landmarks_fitted[17:], atol=1e-2)  # the prediction is posed in that camera


def test_without_a_camera_the_prediction_takes_the_fits_default(model, faces):
    """Issue 48 ('one front door'): given no camera, the predictor takes the fit's default, an
    unknown focal estimated from the landmarks, as :func:`facegeo.fit` does (not a 40° camera
    taken as known)."""
    from facegeo import fit

    photo, landmarks, predictor, _ = _camera_case(model, faces)
    fitted = fit(photo, model=model, landmarks=landmarks, photometric=False)
    predicted = predictor(photo, landmarks=landmarks)
    assert predicted.camera == fitted.camera and not predicted.camera.focal_known
    assert predicted.camera.focal != pytest.approx(Camera.for_image(96, 96).focal, rel=0.05)


def test_given_landmarks_of_another_shape_are_refused_at_the_front_door(model, faces, tmp_path):
    """The fit and the predictor check given landmarks in the same place (observe_photo), before
    the photo is read: (68, 2) points and a photo that does not exist name the landmarks."""
    from facegeo import fit
    from facegeo.errors import InputError

    _, _, predictor, _ = _camera_case(model, faces)
    for call in (lambda p, lm: fit(p, model=model, landmarks=lm), lambda p, lm: predictor(p, landmarks=lm)):
        with pytest.raises(InputError, match=r"landmarks: expected shape \(88, 2\) in pixels, found \(68, 2\)"):
            call(tmp_path / "missing.png", np.zeros((68, 2)))


def test_refine_fits_in_the_predictions_camera(model, faces):
    """Issue 47: with ``refine`` and an unknown lens the fit starts from the prediction in the
    prediction's camera and estimates no focal of its own (one estimate, one note)."""
    photo, landmarks, predictor, refining = _camera_case(model, faces)
    unknown = Camera.unknown_focal(96, 96)
    predicted = predictor(photo, landmarks=landmarks, camera=unknown)
    refined = refining(photo, landmarks=landmarks, camera=unknown, photometric=False)
    assert refined.info["fitter"] == "regressor+refine" and refined.camera == predicted.camera
    assert len([n for n in refined.info["notes"] if n.startswith("focal length unknown")]) == 1


def test_a_known_focal_is_kept_for_prediction_and_refinement(model, faces):
    photo, landmarks, predictor, refining = _camera_case(model, faces)
    known = Camera(150.0, 47.0, 49.5, 96, 96)
    predicted = predictor(photo, landmarks=landmarks, camera=known)
    refined = refining(photo, landmarks=landmarks, camera=known, photometric=False)
    assert predicted.camera == known and refined.camera == known
    assert not any(n.startswith("focal length") for n in predicted.info["notes"] + refined.info["notes"])


@pytest.mark.slow
def test_training_lowers_the_landmark_loss_and_learns_the_pose(model, tmp_path):
    """A tiny MSSF trained 300 steps on CPU (≈ 3 min on a loaded 2-core machine): the landmark
    loss falls ≥ 5×, the rotation error halves against the frontal guess, and on held-out faces
    the predicted shape (α, δ) stays as close to the truth as the mean shape: the MAP-weighted
    prior keeps the α and δ that this budget cannot learn at the mean face (with the fixed 1e-3
    weight and the sigmoid δ they added 11 % to the error). Not met at this budget: closer than
    the mean shape (the expressions are not learned yet; benchmarks/RESULTS.md)."""
    folder = make_synthetic_faces(tmp_path / "train", 160, model, size=128, seed=11, max_yaw=60)
    held_out = make_synthetic_faces(tmp_path / "test", 24, model, size=128, seed=12, max_yaw=60)
    data = json.loads(json.dumps(TINY))
    data["network"].update(image_size=64, width=32, convnext={"hidden_sizes": [8, 16, 32, 64], "depths": [1, 1, 1, 1]},
                           dino={"hidden_size": 32, "num_hidden_layers": 2, "num_attention_heads": 2, "intermediate_size": 64})
    data["train"].update(batch_size=16, epochs=100, lr=1e-3, augment=False)
    config = RegressorConfig.from_dict(data)
    table, _ = landmark_table(list_images(folder), tmp_path / "lm.npz", "truth", 1024, progress=False)
    crops = FaceCrops(list(table.values()), 64, config.network.crop_scale, augment=False)
    objective = Objective(model, config.loss, 64)
    with torch.random.fork_rng():
        torch.manual_seed(config.train.seed)  # the network train() starts from
        start = MSSFRegressor(config.network, ModelSignature.of(model))
    before = evaluate(start, objective, crops)["lan"]
    train(folder, tmp_path / "run", config, model=model, progress=False, max_steps=300)
    predictor = load(tmp_path / "run" / "last.pt", model=model)
    after = evaluate(predictor.network, objective, crops)["lan"]
    assert after * 5 <= before, (before, after)
    truth = np.load(folder / "faces.npz")
    from facegeo import load_photo

    def angle(r: np.ndarray) -> float:
        return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))

    errors, frontal = [], []
    for i in range(0, 160, 8):
        got = predictor(load_photo(folder / str(truth["names"][i])), landmarks=truth["landmarks"][i])
        errors.append(angle(got.rotation.astype(np.float64) @ truth["rotation"][i].T))
        frontal.append(angle(truth["rotation"][i].T.astype(np.float64)))
    assert np.mean(errors) < 0.6 * np.mean(frontal), (np.mean(errors), np.mean(frontal))
    test = np.load(held_out / "faces.npz")
    face = model.face_mask
    predicted, mean = [], []
    for i, name in enumerate(test["names"]):
        true = model.shape(torch.from_numpy(test["alpha"][i]), torch.from_numpy(test["delta"][i])).numpy()[face]
        got = predictor(load_photo(held_out / str(name)), landmarks=test["landmarks"][i])
        predicted.append(similarity_rms(got.shape_vertices[face], true))
        mean.append(similarity_rms(model.mean_shape[face], true))
    assert np.mean(predicted) < 1.03 * np.mean(mean), (np.mean(predicted), np.mean(mean))
