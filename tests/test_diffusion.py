"""The diffusion texture stack on tiny, randomly initialised models (CPU, seconds).

Skipped when the optional [diffusion] extra is not installed.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("diffusers")
pytest.importorskip("peft")

from diffusers.models.transformers.transformer_longcat_image import LongCatImageAttnProcessor  # noqa: E402

from facegeo.cli import main  # noqa: E402
from facegeo.errors import InputError  # noqa: E402
from facegeo.texturing.diffusion.attention import CrossIntrinsicAttention, cross_intrinsic  # noqa: E402
from facegeo.texturing.diffusion.backend import LORA_FILE, SR_FILE, DiffusionBackend  # noqa: E402
from facegeo.texturing.diffusion.components import save_components, tiny_components  # noqa: E402
from facegeo.texturing.diffusion.data import (  # noqa: E402
    make_pair, pack_rsd, procedural_pbr_set, read_pbr_set, read_samples, uniform_white_lights, unpack_rsd, write_pbr_set,
)
from facegeo.texturing.diffusion.lpips import LPIPS, load_lpips  # noqa: E402
from facegeo.texturing.diffusion.model import (  # noqa: E402
    ADALN_TARGETS, LORA_TARGETS, MATERIAL_BRANCHES, TASKS, add_adapters, decode, encode, lora_parameters, mixed_adapters, pack, unpack, velocity,
)
from facegeo.texturing.diffusion.sampling import sample  # noqa: E402
from facegeo.texturing.diffusion.sr import RRDBNet, load_realesrgan, upscale_tiled  # noqa: E402
from facegeo.texturing.diffusion.training import (  # noqa: E402
    ShadingSupervisor, TrainConfig, encode_samples, flow_matching_step, maps_from_images, train_lora, validation_loss,
)

torch.set_num_threads(1)


def _tokens(seed: int, batch: int, grid: int = 4, text: int = 8) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    noisy = torch.randn(batch, grid * grid, 16, generator=g)
    cond = torch.randn(batch, grid * grid, 16, generator=g)
    prompt = torch.randn(batch, text, 32, generator=g)
    return noisy, cond, prompt, torch.rand(batch, generator=g)


# ------------------------------------------------------------------------ cross-intrinsic attention
def test_cross_intrinsic_with_one_modality_is_the_stock_processor():
    c = tiny_components()
    noisy, cond, prompt, sigma = _tokens(0, 2)
    stock = velocity(c.transformer, noisy, cond, prompt, sigma, (4, 4))
    with cross_intrinsic(c.transformer, 1):
        ours = velocity(c.transformer, noisy, cond, prompt, sigma, (4, 4))
    assert torch.equal(stock, ours)
    assert all(isinstance(p, LongCatImageAttnProcessor) for p in c.transformer.attn_processors.values())  # restored


def test_cross_intrinsic_couples_the_branches():
    c = tiny_components()
    noisy, cond, prompt, sigma = _tokens(1, 3)
    bumped = noisy.clone()
    bumped[1] += torch.randn(bumped[1].shape, generator=torch.Generator().manual_seed(5))  # the normal branch only

    def run(x: torch.Tensor, modalities: int) -> torch.Tensor:
        with cross_intrinsic(c.transformer, modalities):
            return velocity(c.transformer, x, cond, prompt, sigma.repeat(1), (4, 4))

    independent = run(noisy, 1), run(bumped, 1)
    joint = run(noisy, 3), run(bumped, 3)
    assert torch.equal(independent[0][0], independent[1][0])  # without it the albedo branch does not see the normal branch
    assert (joint[0][0] - joint[1][0]).abs().max() > 1e-4  # with it, it does
    assert torch.equal(joint[0][2], joint[0][2]) and (joint[0][2] - joint[1][2]).abs().max() > 1e-4


def test_cross_intrinsic_on_identical_branches_is_self_attention_over_repeated_tokens():
    c = tiny_components()
    attn = c.transformer.transformer_blocks[0].attn
    g = torch.Generator().manual_seed(2)
    x, ctx = torch.randn(1, 16, 32, generator=g), torch.randn(1, 8, 32, generator=g)
    stock = LongCatImageAttnProcessor()(attn, x, ctx)
    ours = CrossIntrinsicAttention(3)(attn, x.repeat(3, 1, 1), ctx.repeat(3, 1, 1))
    # reference: softmax over the tokens written three times (weights 1/3 each copy)
    q = torch.cat([attn.norm_added_q(attn.add_q_proj(ctx).unflatten(-1, (2, -1))), attn.norm_q(attn.to_q(x).unflatten(-1, (2, -1)))], 1)
    k = torch.cat([attn.norm_added_k(attn.add_k_proj(ctx).unflatten(-1, (2, -1))), attn.norm_k(attn.to_k(x).unflatten(-1, (2, -1)))], 1)
    v = torch.cat([attn.add_v_proj(ctx).unflatten(-1, (2, -1)), attn.to_v(x).unflatten(-1, (2, -1))], 1)
    k3, v3 = k.repeat(1, 3, 1, 1), v.repeat(1, 3, 1, 1)
    ref = torch.softmax(torch.einsum("blhd,bmhd->bhlm", q, k3) / 4.0, -1)
    ref = torch.einsum("bhlm,bmhd->blhd", ref, v3).flatten(2)
    ref_img, ref_ctx = attn.to_out[0](ref[:, 8:]), attn.to_add_out(ref[:, :8])
    for i in range(3):
        torch.testing.assert_close(ours[0][i : i + 1], ref_img, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(ours[1][i : i + 1], ref_ctx, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(ours[0][i : i + 1], stock[0], rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------------ LoRAs
def test_mixed_adapters_match_single_adapter_runs_and_only_lora_weights_train():
    c = tiny_components()
    add_adapters(c.transformer, MATERIAL_BRANCHES, rank=4)
    with torch.no_grad():
        for p in lora_parameters(c.transformer, MATERIAL_BRANCHES):
            p.normal_(0, 0.3)  # B is initialised to 0; give every adapter an effect
    noisy, cond, prompt, sigma = _tokens(3, 3)
    with mixed_adapters(c.transformer, MATERIAL_BRANCHES):
        mixed = velocity(c.transformer, noisy, cond, prompt, sigma, (4, 4))
    for i, name in enumerate(MATERIAL_BRANCHES):
        with mixed_adapters(c.transformer, [name]):
            alone = velocity(c.transformer, noisy[i : i + 1], cond[i : i + 1], prompt[i : i + 1], sigma[i : i + 1], (4, 4))
        torch.testing.assert_close(mixed[i : i + 1], alone, rtol=1e-5, atol=1e-6)
    trainable = {n for n, p in c.transformer.named_parameters() if p.requires_grad}
    assert trainable and all("lora_" in n for n in trainable)


def test_lora_save_load_reproduces_outputs_exactly(tmp_path):
    c = tiny_components()
    add_adapters(c.transformer, ["inpaint"], rank=4)
    with torch.no_grad():
        for p in lora_parameters(c.transformer, ["inpaint"]):
            p.normal_(0, 0.3)
    c.transformer.save_lora_adapter(tmp_path / "inpaint", adapter_name="inpaint")
    fresh = tiny_components()  # same seed: the same base weights
    fresh.transformer.load_lora_adapter(str(tmp_path / "inpaint"), weight_name=LORA_FILE, use_safetensors=True,
                                        adapter_name="inpaint", prefix=None)
    noisy, cond, prompt, sigma = _tokens(4, 2)
    outs = []
    for comp in (c, fresh):
        with mixed_adapters(comp.transformer, ["inpaint"] * 2):
            outs.append(velocity(comp.transformer, noisy, cond, prompt, sigma, (4, 4)))
    base = velocity(fresh.transformer.__class__(**fresh.transformer.config).eval(), noisy, cond, prompt, sigma, (4, 4))
    assert torch.equal(outs[0], outs[1])
    assert not torch.allclose(outs[0], base)


# ------------------------------------------------------------------------ data
@pytest.fixture(scope="module")
def pairs(tmp_path_factory) -> Path:
    """Four pairs of 16² texels from two procedural PBR sets, made with the CLI."""
    root = tmp_path_factory.mktemp("pairs")
    write_pbr_set(root / "sets" / "skin_a", procedural_pbr_set(64, np.random.default_rng(1)))
    status = main(["make-texture-pairs", str(root / "sets" / "skin_a"), "--procedural", "1", "--samples", "2",
                   "--size", "16", "--image-size", "96", "-o", str(root / "out")])
    assert status == 0
    return root / "out"


def test_texture_pairs_are_consistent(pairs):
    data = read_samples(pairs)
    assert all(v.shape[0] == 4 for v in data.values())
    visible = data["m_vis"] > 0.99
    assert 0.1 < visible.mean() < 0.9  # a pose shows part of the head
    # where fully visible, the unwrapped photo is the shaded texture (bilinear resampling aside)
    err = np.abs(data["t_inc"] - data["t_env"])[visible].mean()
    assert err < 0.06
    assert np.abs(data["t_inc"][~(data["m_vis"] > 0)]).max() == 0.0


def test_pbr_set_files_round_trip_and_rsd_packing(tmp_path):
    maps = procedural_pbr_set(32, np.random.default_rng(0))
    write_pbr_set(tmp_path / "s", maps, displacement_mm=0.1)
    back = read_pbr_set(tmp_path / "s", 32, displacement_mm=0.1)
    for name in maps:
        np.testing.assert_allclose(back[name], maps[name], atol=2e-4 if name != "normal" else 1e-3)
    rsd = unpack_rsd(pack_rsd(maps["roughness"], maps["specular"], maps["displacement"]))
    for name in ("roughness", "specular", "displacement"):
        np.testing.assert_allclose(rsd[name], maps[name], atol=1e-6)
    (tmp_path / "s" / "specular.png").unlink()
    with pytest.raises(InputError, match="specular.png"):
        read_pbr_set(tmp_path / "s", 32)


def test_uniform_white_light_gives_lambertian_albedo():
    dirs, radiance = uniform_white_lights(64)
    normals = np.random.default_rng(0).normal(size=(100, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    irradiance = (np.maximum(normals @ dirs.T, 0) * radiance[:, 0]).sum(1)
    np.testing.assert_allclose(irradiance, np.pi, rtol=0.03)


# ------------------------------------------------------------------------ training
def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1.0 / ((a.clamp(0, 1) - b.clamp(0, 1)) ** 2).mean()))


def test_a_few_hundred_steps_lower_the_loss_five_times_and_improve_samples(pairs, tmp_path):
    """The issue's bar on the one-layer backbone: an inpaint LoRA (the paper's rank 32), 300 steps
    of batch 8 on 2 pairs. The loss is :func:`validation_loss` on a fixed σ grid and fixed noise,
    before and after; its Bayes floor on this data is 0 (the two conditions differ, so the optimal
    velocity (z_σ − z₀)/σ is exact). The adapter also covers the AdaLN modulation
    (``ADALN_TARGETS``): with this random backbone's modulation frozen, LoRAs on the paper's
    targets alone reach 2.39× (benchmarks/RESULTS.md, "Training bar")."""
    c = tiny_components()
    lat = encode_samples(c, {k: v[:2] for k, v in read_samples(pairs, ("t_inc", "t_env")).items()}, "inpaint")
    n = lat.condition.shape[0]
    add_adapters(c.transformer, ["inpaint"], targets=LORA_TARGETS + ADALN_TARGETS)

    def psnr_of_samples() -> float:
        z = sample(c.transformer, c.scheduler, lat.condition, c.prompt("inpaint").expand(n, -1, -1),
                   c.prompt("negative").expand(n, -1, -1), lat.grid, adapters=["inpaint"] * n, steps=8, guidance=1.0,
                   generator=torch.Generator().manual_seed(0))
        with torch.no_grad():  # against the targets as the VAE reproduces them (the tiny VAE is untrained)
            return _psnr(decode(c.vae, unpack(z, *lat.latent_hw)), decode(c.vae, unpack(lat.targets[0], *lat.latent_hw)))

    before, psnr_before = validation_loss(c, lat, "inpaint"), psnr_of_samples()
    run = tmp_path / "run"
    rows = train_lora(c, lat, TrainConfig(task="inpaint", steps=300, batch=8, lr=5e-3, save_every=10**6, caption_dropout=0.0),
                      run, progress=False)
    assert len(rows) == 300 and (run / "inpaint" / LORA_FILE).is_file()
    after, psnr_after = validation_loss(c, lat, "inpaint"), psnr_of_samples()
    assert float(before.mean() / after.mean()) >= 5.0, (before, after)  # measured 2.242 -> 0.276, 8.12×
    assert bool((after < before).all()), (before, after)  # lower at every σ of the grid
    assert psnr_after > psnr_before + 3.0, (psnr_before, psnr_after)  # measured 14.34 -> 24.42 dB


def test_joint_materials_step_gradients(pairs):
    c = tiny_components()
    data = read_samples(pairs, ("t_hom", "albedo", "normal", "rsd"))
    lat = encode_samples(c, data, "materials")
    add_adapters(c.transformer, MATERIAL_BRANCHES, rank=4)
    supervisor = ShadingSupervisor(16)
    out = flow_matching_step(c, lat, "materials", torch.tensor([0, 2]), torch.Generator().manual_seed(0), joint=True, supervisor=supervisor)
    assert set(out) == {"loss", "diff", "img"} and torch.isfinite(out["loss"])
    out["loss"].backward()
    grads = {n: p.grad for n, p in c.transformer.named_parameters() if p.grad is not None}
    assert grads and all("lora_" in n for n in grads)  # only LoRA weights get gradients
    for name in MATERIAL_BRANCHES:  # every branch's adapter does (B starts at 0, so A's gradient is 0)
        assert any(f"lora_B.{name}." in n and g.abs().sum() > 0 for n, g in grads.items()), name
    assert all(p.grad is None for p in c.vae.parameters())


def test_shading_loss_gradient_reaches_all_five_maps():
    supervisor = ShadingSupervisor(32)
    g = torch.Generator().manual_seed(0)
    images = [torch.rand(2, 3, 32, 32, generator=g).requires_grad_(True) for _ in range(3)]
    target = maps_from_images(*[torch.rand(2, 3, 32, 32, generator=g) for _ in range(3)])
    predicted = maps_from_images(*images)
    for m in predicted.values():
        m.retain_grad()
    views = supervisor.sample_views(2, g)
    mse, perceptual = supervisor.losses(predicted, target, views)
    assert perceptual is None and float(mse.detach()) > 0
    mse.backward()
    for name, m in predicted.items():
        assert m.grad is not None and m.grad.abs().sum() > 0, name


def test_train_lora_cli_materials_checkpoints_and_resume(pairs, tmp_path, capsys):
    c = tiny_components()
    base = save_components(c, tmp_path / "base")
    run = tmp_path / "run"
    args = ["train-lora", "--task", "materials", "--data", str(pairs), "--base", str(base), "--out", str(run),
            "--batch", "2", "--rank", "4", "--save-every", "2"]
    assert main([*args, "--steps", "2", "--joint-steps", "0"]) == 0  # stage 1 only, then stopped
    assert main([*args, "--steps", "4", "--joint-steps", "2", "--resume"]) == 0
    assert "LPIPS term of the shading loss is dropped" in capsys.readouterr().out
    rows = (run / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("step,stage,loss") and [r.split(",")[0] for r in rows[1:]] == ["1", "2", "3", "4"]
    assert [r.split(",")[1] for r in rows[1:]] == ["1", "1", "2", "2"]  # independent, then joint
    assert all(r.split(",")[4] != "" for r in rows[3:])  # the joint stage has the shading term
    for name in MATERIAL_BRANCHES:
        assert (run / name / "pytorch_lora_weights.safetensors").is_file()
    assert (run / "checkpoint-4" / "state.pt").is_file()


# ------------------------------------------------------------------------ SR and LPIPS
def test_realesrgan_loads_the_official_key_layout_and_tiles_exactly(tmp_path):
    torch.manual_seed(0)
    net = RRDBNet(feat=8, blocks=2, grow=4).eval()
    state = net.state_dict()
    assert {"conv_first.weight", "body.1.rdb3.conv5.bias", "conv_body.weight", "conv_up1.weight", "conv_up2.weight",
            "conv_hr.weight", "conv_last.weight"} <= set(state)
    torch.save({"params_ema": state}, tmp_path / SR_FILE)
    loaded = load_realesrgan(tmp_path / SR_FILE)
    x = torch.rand(1, 3, 12, 12)
    with torch.no_grad():
        assert torch.equal(loaded(x), net(x))
    image = np.random.default_rng(0).random((20, 28, 3)).astype(np.float32)
    with torch.no_grad():
        whole = net(torch.nn.functional.pad(torch.from_numpy(image.transpose(2, 0, 1))[None], (40,) * 4, mode="replicate"))
    whole = whole[0, :, 160:-160, 160:-160].clamp(0, 1).permute(1, 2, 0).numpy()
    np.testing.assert_allclose(upscale_tiled(loaded, image, tile=8, pad=40), whole, atol=1e-5)
    torch.save({"params": {"conv_first.weight": torch.zeros(1)}}, tmp_path / "bad.pth")
    with pytest.raises(InputError, match="RRDBNet keys"):
        load_realesrgan(tmp_path / "bad.pth")


def test_lpips_reads_its_layout(tmp_path):
    torch.manual_seed(0)
    model = LPIPS()
    for p in model.parameters():
        p.data.uniform_(0, 0.1)
    torch.save(model.state_dict(), tmp_path / "lpips.pth")
    loaded = load_lpips(tmp_path / "lpips.pth")
    x, y = torch.rand(1, 3, 32, 32) * 2 - 1, torch.rand(1, 3, 32, 32) * 2 - 1
    assert float(loaded(x, x)) == 0.0 and float(loaded(x, y)) == pytest.approx(float(model(x, y)))
    assert "net.slice3.14.weight" in model.state_dict() and "lin4.model.1.weight" in model.state_dict()
    torch.save({k: v for k, v in model.state_dict().items() if not k.startswith("lin")}, tmp_path / "net_only.pth")
    with pytest.raises(InputError, match="lin0.model.1.weight"):
        load_lpips(tmp_path / "net_only.pth")


# ------------------------------------------------------------------------ the backend
@pytest.fixture(scope="module")
def weights(tmp_path_factory) -> Path:
    """A weights folder: the tiny base, five random adapters and a tiny SR network."""
    root = tmp_path_factory.mktemp("weights")
    c = tiny_components()
    save_components(c, root / "base")
    add_adapters(c.transformer, TASKS, rank=4)
    with torch.no_grad():
        for p in lora_parameters(c.transformer, TASKS):
            p.normal_(0, 0.1)
    for task in TASKS:
        c.transformer.save_lora_adapter(root / "loras" / task, adapter_name=task)
    (root / "sr").mkdir()
    torch.save({"params_ema": RRDBNet(feat=8, blocks=1, grow=4).state_dict()}, root / "sr" / SR_FILE)
    return root


def test_backend_stages_shapes_and_map_subsets(weights):
    from facegeo.texturing.backend import TextureBackend, TextureContext

    backend = DiffusionBackend.from_weights(weights, resolution=32, steps=2)
    assert isinstance(backend, TextureBackend) and (backend.steps, backend.guidance) == (2, 2.0)
    S = 48
    rng = np.random.default_rng(0)
    cover = np.zeros((S, S), bool)
    cover[4:44, 4:44] = True
    ctx = TextureContext(cover, np.zeros((S, S, 3), np.float32), np.zeros((S, S, 3), np.float32), np.ones((S, S, 2), np.float32),
                         np.zeros((3, 9), np.float32), np.full((S, S, 3), 0.5, np.float32), -np.ones((S, S, 2), np.int32))
    t_inc = rng.random((S, S, 3)).astype(np.float32)
    full = backend.inpaint(t_inc, (rng.random((S, S)) > 0.5).astype(np.float32), ctx)
    hom = backend.homogenise(full, ctx)
    assert full.shape == hom.shape == (S, S, 3) and full.dtype == np.float32 and 0 <= full.min() and full.max() <= 1
    maps = backend.materials(hom, ctx)
    assert {k: v.shape for k, v in maps.items()} == {"albedo": (S, S, 3), "normal": (S, S, 3), "roughness": (S, S),
                                                     "specular": (S, S), "displacement": (S, S)}
    np.testing.assert_allclose(np.linalg.norm(maps["normal"], axis=-1), 1.0, atol=1e-5)
    assert np.abs(maps["displacement"]).max() <= 1.0
    assert set(backend.materials(hom, ctx, {"roughness"})) == {"roughness"}
    assert backend.upscale(maps["roughness"], 4).shape == (4 * S, 4 * S)
    assert backend.upscale(maps["normal"], 2).shape == (2 * S, 2 * S, 3)
    assert set(backend.report) == {"inpaint", "homogenise", "albedo+normal+rsd", "rsd"} and backend.report["rsd"]["steps"] == 2
    again = DiffusionBackend.from_weights(weights, resolution=32, steps=2).homogenise(full, ctx)
    assert np.array_equal(again, hom)  # seeded


def test_missing_weights_are_all_named_before_any_work(weights, tmp_path, capsys):
    partial = tmp_path / "w"
    (partial / "base").mkdir(parents=True)
    (partial / "base" / "vae").symlink_to(weights / "base" / "vae")
    (partial / "loras").mkdir()
    (partial / "loras" / "inpaint").symlink_to(weights / "loras" / "inpaint")
    with pytest.raises(InputError) as err:
        DiffusionBackend.from_weights(partial)
    message = str(err.value)
    for missing in ("transformer/config.json", "prompt_embeds.safetensors", "loras/homogenise", "loras/rsd", SR_FILE):
        assert missing in message
    assert "loras/inpaint" not in message and "vae/config.json" not in message
    status = main(["reconstruct", str(tmp_path / "no_such_photo.png"), "-o", str(tmp_path / "out"), "--backend", "diffusion",
                   "--weights", str(partial)])
    err_lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err_lines) == 1 and "transformer/config.json" in err_lines[0] and "no_such_photo" not in err_lines[0]
    assert not (tmp_path / "out").exists()


def test_core_install_does_not_import_the_diffusion_stack():
    heavy = "('diffusers', 'peft', 'transformers', 'torch', 'cv2')"
    code = (f"import sys, facegeo.cli; facegeo.cli.build_parser(); print([m for m in {heavy} if m in sys.modules]); "
            f"import facegeo.pipeline; print([m for m in {heavy}[:3] if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["[]", "[]"]  # the parser (with train-lora etc.) imports nothing heavy; the pipeline not the extra


@pytest.mark.slow
def test_reconstruct_with_the_diffusion_backend(weights):
    """The whole pipeline on the bundled photo with the tiny weights (a wiring test: the maps are noise)."""
    from facegeo.pipeline import reconstruct

    backend = DiffusionBackend.from_weights(weights, resolution=32, steps=2)
    photo = Path(__file__).resolve().parents[1] / "assets" / "photos" / "astronaut.png"
    asset = reconstruct(photo, backend=backend, size=64, upscale=2)
    assert asset.metadata["backend"] == "diffusion"
    assert {k: v.shape[:2] for k, v in asset.maps.items()} == {k: (128, 128) for k in ("albedo", "normal", "roughness", "specular", "displacement")}
    assert set(asset.metadata["texture_report"]) == {"inpaint", "homogenise", "albedo+normal+rsd"}
    asset.validate("<test>")
