"""The reconstruct command end to end on a tiny run with an analytic sphere decoder swapped in."""

import dataclasses
import json

import numpy as np
import pytest
import torch
from fake_world import write_sdf

from ushape.data.cameras import camera_centre
from ushape.data.layout import WorldIndex
from ushape.fusion import BayesianKFusion
from ushape.propagation import SDF_CLAMP
from ushape.propagation.monte_carlo import sample_codes
from ushape.recalibration import floor_grid
from ushape.recalibration.sdf_distance import DISTANCE_GRID
from ushape.reconstruction.cli import build_fusion, main
from ushape.reconstruction.export import read_glb_std, read_ply_std
from ushape.reconstruction.pipeline import reconstruct
from ushape.reconstruction.predictor import load_predictor
from ushape.reconstruction.settings import ReconstructionSettings
from ushape.reconstruction.view_depth import view_camera
from ushape.refinement.joint import PoseSettings

SMALL = ReconstructionSettings(resolution=24, depth_size=16, depth_codes=4, depth_steps=40)


def test_reconstruct_writes_every_output(tiny_run, sphere_predictor, tmp_path):
    views = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))
    summary = reconstruct(sphere_predictor, views, BayesianKFusion(k=2), tmp_path / "out", SMALL)
    out = tmp_path / "out"
    assert json.loads((out / "summary.json").read_text()) == summary
    assert len(summary["views"]) == 3 and summary["fusion"] == "bayesian-2"
    assert summary["precision"]["requested"] == summary["settings"]["precision"] == "auto"
    assert summary["precision"]["resolved"] in ("fp32", "bf16") and summary["precision"]["why"]
    assert summary["fused"]["kept"] == sorted(summary["fused"]["kept"]) and len(summary["fused"]["kept"]) == 2
    traces = [v["trace_var"] for v in summary["views"]]
    dropped = [i for i, v in enumerate(summary["views"]) if not v["kept"]]
    assert len(dropped) == 1  # bayesian-k drops the most uncertain view
    assert traces[dropped[0]] >= max(t for i, t in enumerate(traces) if i != dropped[0])
    for key in ("ply", "glb", "colour_bar", "overview"):
        assert (out / summary["files"][key].split("/")[-1]).is_file()
    std_ply, std_glb = read_ply_std(summary["files"]["ply"]), read_glb_std(summary["files"]["glb"])
    assert np.array_equal(std_ply, std_glb) and len(std_ply) == summary["mesh"]["vertices"]  # one array, two files
    # linearised: std = 0.1 (1 + x) sqrt(var_0), largest on the +x side of the sphere
    import trimesh

    vertices = trimesh.load(summary["files"]["ply"], process=False).vertices
    assert np.allclose(np.linalg.norm(vertices, axis=1), 0.5, atol=0.02)  # mu = 0: the radius-0.5 sphere
    fused_var = summary["fused"]["trace_var"] / 8
    assert np.allclose(std_ply, 0.1 * (1 + vertices[:, 0]) * np.sqrt(fused_var), rtol=1e-3, atol=1e-6)
    checked = 0
    for view in summary["views"]:
        assert view["depth"]["camera"] == "render" and view["depth"]["hit_pixels"] > 0
        # The std grows towards +x, so a camera on the -x side sees the surer half: hidden/visible > 1.
        with np.load(view["depth"]["npz"]) as depth:
            assert depth["mean"].shape == (16, 16)
            camera_x = camera_centre(depth["world_to_cam"])[0]
        seen = view["visibility"]
        assert seen["hidden_vertices"] > 0 and seen["visible_vertices"] > 0
        if abs(camera_x) > 0.3:
            assert (seen["std_hidden_over_visible"] > 1) == (camera_x < 0)
            checked += 1
    assert checked > 0
    assert set(summary["seconds"]) >= {"encode", "fuse", "mesh", "vertex_uncertainty", "depth_uncertainty"}


def test_view_camera_uses_the_render_camera_or_the_canonical_one(tiny_run, tmp_path):
    K, w2c, kind = view_camera(tiny_run["world"] / "renders" / "val_0" / "01.png", 12)
    with np.load(tiny_run["world"] / "renders" / "val_0" / "views.npz") as cams:
        assert kind == "render" and np.allclose(w2c, cams["world_to_cam"][1])
        assert np.allclose(K[:2], cams["K"][1][:2] * 0.5)  # rendered at 24 px, traced at 12
    assert view_camera(tmp_path / "photo.jpg", 12)[2] == "canonical"


def test_cli_reports_skipped_images_and_bad_fusion(tiny_run, tmp_path, capsys, monkeypatch):
    assert isinstance(build_fusion("bayesian_k", 3), BayesianKFusion) and build_fusion("bayesian_k", 3).k == 3
    with pytest.raises(ValueError, match="unknown fusion"):
        build_fusion("median")
    assert main([str(tmp_path / "nothing.png"), "--run", str(tiny_run["run"]), "--out", str(tmp_path / "o")]) == 2
    assert "none of the 1 input" in capsys.readouterr().err and not (tmp_path / "o").exists()
    monkeypatch.setattr("ushape.reconstruction.predictor.latest_run", lambda root: tiny_run["run"])
    world = WorldIndex(tiny_run["world"], category="", splits={})
    points = np.random.default_rng(0).uniform(-1, 1, (400, 3))
    for shape_id in ("val_0", "val_1", "val_2"):  # ground-truth SDF samples (a sphere) for the SDF factor
        write_sdf(world, shape_id, np.concatenate([points, np.linalg.norm(points, axis=1, keepdims=True) - 0.5], 1))
    assert main(["--fit-temperature"]) == 0
    record = json.loads((tiny_run["checkpoint"].parent / "temperature.json").read_text())
    assert record["n_images"] == 9 and record["temperature"] > 0 and record["nll_after"] <= record["nll_before"]
    # The SDF-space factor, fitted on the val shapes' SDF samples; never worse than none (T = 1 is on the grid).
    assert record["sdf_temperature"] > 0 and record["sdf_calibration_after"] <= record["sdf_calibration_before"]
    assert record["sdf_views"] == 9  # 3 val shapes x 3 renders, all within the first 4 views
    # The shared rule's own SDF factor, on its val views fused 1 and 3 at a time (3 views a shape: no 10).
    shared = record["shared_error"]
    assert shared["sdf_view_counts"] == [1, 3] and shared["sdf_temperature"] > 0
    # Fitted to the worst error over the view counts and their samples near the surface (what the mesh shows).
    assert max(shared["sdf_calibration_after"]) <= shared["sdf_calibration_worst"]
    assert shared.get("sdf_distance_scale") in (None, *DISTANCE_GRID[1:])  # no distance term: b = 0, not stored
    # The decoder's misfit at the val shapes' own codes, an RMS in clamped SDF units, sets the scale of the
    # floors tried with the factor; the pair kept is one of them (none: 0, not stored).
    misfit = shared["sdf_decoder_misfit"]
    assert 0 < misfit <= 2 * SDF_CLAMP and shared.get("sdf_floor") in (None, *floor_grid(misfit)[1:])
    predictor = load_predictor(tiny_run["run"], temperature=True)
    assert predictor.sdf_temperature == record["sdf_temperature"]
    (tiny_run["checkpoint"].parent / "temperature.json").unlink()
    for shape_id in ("val_0", "val_1", "val_2"):
        world.sdf_path(shape_id).unlink()


def test_depth_method_mc_and_implicit_both_run_and_the_summary_says_which(
    tiny_run, sphere_predictor, tmp_path, monkeypatch
):
    views = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[:2]
    monkeypatch.setattr("ushape.reconstruction.cli.open_model", lambda *args, **kwargs: sphere_predictor)
    summaries = {}
    for method in ("mc", "implicit"):
        out = tmp_path / method
        assert (
            main(
                [
                    *map(str, views),
                    "--run",
                    str(tiny_run["run"]),
                    "--out",
                    str(out),
                    "--resolution",
                    "24",
                    "--depth-size",
                    "12",
                    "--depth-codes",
                    "3",
                    "--depth-method",
                    method,
                    *(["--precision", "bf16"] if method == "mc" else []),
                ]
            )
            == 0
        )
        summaries[method] = json.loads((out / "summary.json").read_text())
    for method, summary in summaries.items():
        assert summary["depth_method"] == summary["settings"]["depth_method"] == method
        assert {"depth_uncertainty", "depth_files"} <= set(summary["seconds"])
        for view in summary["views"]:
            assert view["depth"]["method"] == method and view["depth"]["codes"] == (3 if method == "mc" else None)
            with np.load(view["depth"]["npz"]) as depth:
                hit = depth["hit_rate"] > 0
                assert hit.any() and np.isfinite(depth["std"][hit]).all() and (depth["std"][hit] > 0).all()
                if method == "implicit":
                    assert set(np.unique(depth["hit_rate"])) <= {0.0, 1.0}
    assert ReconstructionSettings().depth_method == "implicit"
    with pytest.raises(ValueError, match="depth_method must be one of"):
        reconstruct(
            sphere_predictor,
            views,
            BayesianKFusion(k=2),
            tmp_path / "bad",
            ReconstructionSettings(resolution=24, depth_method="sampled"),
        )
    with pytest.raises(SystemExit):
        main([str(views[0]), "--depth-method", "sampled"])
    assert summaries["mc"]["precision"] == {"requested": "bf16", "resolved": "bf16", "why": "asked for"}


class CorrelatedFusion:
    """Bayesian-2 fusion returned as a full covariance: z_0's variance doubled, every pair correlated 0.8."""

    name = "bayesian-2-full"

    def __call__(self, mu, var):
        fused = BayesianKFusion(k=2)(mu, var)
        std = fused.var.sqrt() * torch.tensor([2.0**0.5] + [1.0] * (len(fused.var) - 1))
        correlation = torch.full((len(std), len(std)), 0.8) + 0.2 * torch.eye(len(std))
        return fused._replace(var=std[:, None] * correlation * std[None, :])


@pytest.mark.parametrize("uncertainty, depth_method", [("linearised", "implicit"), ("mc", "mc")])
def test_reconstruct_takes_a_full_covariance(tiny_run, sphere_predictor, tmp_path, uncertainty, depth_method):
    """The sphere's SDF reads z_0 alone: std = 0.1 (1 + x) sqrt(Sigma_00) linearised, and with MC the same with
    the std of z_0 over the codes drawn from the full covariance (the run's first draw from its seed)."""
    views = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))
    settings = ReconstructionSettings(
        resolution=24, uncertainty=uncertainty, n_samples=20, depth_size=16, depth_method=depth_method, depth_steps=40
    )
    fusion = CorrelatedFusion()
    summary = reconstruct(sphere_predictor, views, fusion, tmp_path / "out", settings)
    mu, var = sphere_predictor.encode(sphere_predictor.load_images(views)[0])
    fused = fusion(mu, var)
    cov = fused.var
    assert summary["fused"]["trace_var"] == pytest.approx(float(torch.trace(cov)), rel=1e-6)
    assert summary["fused"]["covariance"] == "full"
    import trimesh

    vertices = trimesh.load(summary["files"]["ply"], process=False).vertices
    spread = float(cov[0, 0]) ** 0.5
    if uncertainty == "mc":
        spread = float(sample_codes(fused.mu, cov, 20, torch.Generator().manual_seed(settings.seed))[:, 0].std())
    expected = 0.1 * (1 + vertices[:, 0]) * spread
    np.testing.assert_allclose(read_ply_std(summary["files"]["ply"]), expected, rtol=1e-3, atol=1e-6)
    for view in summary["views"]:
        with np.load(view["depth"]["npz"]) as depth:
            hit = depth["hit_rate"] > 0
            assert hit.any() and np.isfinite(depth["std"][hit]).all() and (depth["std"][hit] > 0).all()


def test_refine_masks_on_renders_records_the_refinement_and_meshes_the_posterior(tiny_run, sphere_predictor, tmp_path):
    views = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[:2]
    settings = dataclasses.replace(SMALL, refine="masks", refine_size=12, refine_starts=2)
    summary = reconstruct(sphere_predictor, views, BayesianKFusion(k=2), tmp_path / "out", settings)
    record = summary["refinement"]
    assert record["mode"] == "masks" and record["views_with_camera"] == 2 and record["fallback"] is None
    assert record["starts"] == 2  # prior draws scored beside the fused mean, as asked
    assert record["iterations"] >= 1 and record["rows"]["masks"] == 2 * 12 * 12
    assert record["energy_end"] <= record["energy_start"]
    assert np.isfinite(np.asarray(summary["mesh"]["std_mean"]))


def test_refine_without_cameras_says_so_and_keeps_the_fused_code(tiny_run, sphere_predictor, tmp_path, caplog):
    photo = tmp_path / "photo.png"
    photo.write_bytes(sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[0].read_bytes())
    settings = dataclasses.replace(SMALL, refine="depth")
    summary = reconstruct(sphere_predictor, [photo], BayesianKFusion(k=2), tmp_path / "out", settings)
    assert summary["refinement"]["fallback"] == "no view has a camera"
    assert summary["refinement"]["mu"] == summary["fused"]["mu"]
    assert "no camera" in caplog.text
    with pytest.raises(ValueError, match="refine must be one of"):
        reconstruct(
            sphere_predictor, [photo], BayesianKFusion(k=2), tmp_path / "o2", dataclasses.replace(SMALL, refine="x")
        )
    with pytest.raises(ValueError, match="--refine-starts"):
        reconstruct(
            sphere_predictor,
            [photo],
            BayesianKFusion(k=2),
            tmp_path / "o3",
            dataclasses.replace(SMALL, refine="masks", refine_starts=-1),
        )


def test_refine_masks_without_cameras_estimates_the_pose_and_relative_poses_share_one(
    tiny_run, sphere_predictor, tmp_path
):
    renders = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[:2]
    photos = []
    for i, render in enumerate(renders):  # copied away from views.npz: no camera
        photos.append(tmp_path / f"photo{i}.png")
        photos[-1].write_bytes(render.read_bytes())
    settings = dataclasses.replace(SMALL, refine="masks", refine_size=12)
    summary = reconstruct(sphere_predictor, photos, BayesianKFusion(k=2), tmp_path / "out", settings)
    record = summary["refinement"]
    assert record["fallback"] is None and record["views_with_camera"] == 0
    groups = record["pose"]["groups"]
    assert len(groups) == 2 and len(record["pose"]["cameras"]) == 2  # no known motion: a pose per view
    assert all(g["scale_std"] is None for g in groups)  # one view cannot tell size from distance
    with np.load(tiny_run["world"] / "renders" / "test_0" / "views.npz") as data:
        odometry = data["world_to_cam"][:2]
    shifted = np.eye(4)
    shifted[:3, 3] = [0.3, -0.2, 1.0]  # the same motion, written in another frame
    np.savez(tmp_path / "odometry.npz", world_to_cam=odometry @ np.linalg.inv(shifted))
    shared = dataclasses.replace(settings, relative_poses=str(tmp_path / "odometry.npz"))
    summary = reconstruct(sphere_predictor, photos, BayesianKFusion(k=2), tmp_path / "out2", shared)
    groups = summary["refinement"]["pose"]["groups"]
    assert len(groups) == 1 and groups[0]["scale_std"] is not None  # one pose; the baseline tells the size
    # the cameras' elevation and the tilt's prior (--elevation, --tilt-std): a sphere's rotation is unobservable, so
    # its posterior std is the prior's on each of the object's axes, the tilt's about the horizontal x and z
    upright = dataclasses.replace(shared, elevation=20.0, tilt_std=3.0)
    pose = reconstruct(sphere_predictor, photos, BayesianKFusion(k=2), tmp_path / "out6", upright)["refinement"]["pose"]
    assert pose["elevation_deg"] == 20.0 and pose["tilt_prior_deg"] == 3.0
    tilt_x, turn, tilt_z = pose["groups"][0]["rotation_std_deg_axes"]
    prior = PoseSettings()
    about_vertical = prior.rotation_prior_with_head_deg if pose["viewpoint_head"] else prior.rotation_prior_deg
    assert tilt_x == pytest.approx(3.0, rel=1e-3) and tilt_z == pytest.approx(3.0, rel=1e-3)
    assert turn == pytest.approx(about_vertical, rel=1e-3)
    with pytest.raises(ValueError, match="--tilt-std"):
        reconstruct(sphere_predictor, photos, BayesianKFusion(k=2), tmp_path / "o6",
                    dataclasses.replace(upright, tilt_std=0.0))  # fmt: skip
    given = dataclasses.replace(settings, pose="given")
    summary = reconstruct(sphere_predictor, photos, BayesianKFusion(k=2), tmp_path / "out3", given)
    assert summary["refinement"]["fallback"] == "no view has a camera"
    with pytest.raises(ValueError, match="drop --pose given"):
        reconstruct(sphere_predictor, photos, BayesianKFusion(k=2), tmp_path / "o5",
                    dataclasses.replace(shared, pose="given"))  # fmt: skip
    with pytest.raises(ValueError, match="need --refine masks or --refine depth"):
        reconstruct(sphere_predictor, photos, BayesianKFusion(k=2), tmp_path / "o4",
                    dataclasses.replace(SMALL, pose="estimate"))  # fmt: skip


def test_rgbd_frames_without_a_pose_give_the_object_its_size_in_the_depths_units(tiny_run, sphere_predictor, tmp_path):
    """An RGB-D camera's frame: K, mask and depth in a camera file with no world_to_cam (where the cameras stood
    is unknown), --refine depth --pose estimate. The depth makes the scale part of the pose, and the problem is
    the same in any units: depth in units twice as small gives the object twice the scale."""
    from ushape.propagation.sphere_tracing import camera_rays, sphere_trace
    from ushape.refinement.inputs import image_size, input_views

    renders = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[:1]
    photo = tmp_path / "frame.png"
    photo.write_bytes(renders[0].read_bytes())
    with np.load(tiny_run["world"] / "renders" / "test_0" / "views.npz") as data:
        K, w2c = data["K"][:1], data["world_to_cam"][0]
    h, w = image_size(photo)  # the decoder's own sphere seen through the render's camera: its depth and mask
    o, d = camera_rays(K[0], w2c, (h, w), 1, 1e-3)
    decoder = sphere_predictor.decoder
    with torch.no_grad():
        t, hit = sphere_trace(lambda x, _: decoder(x, torch.zeros(x.shape[0], 8)), o, d, 1, 100, 1e-4)
    depth = torch.where(hit[0], t[0], torch.zeros_like(t[0])).reshape(1, h, w).numpy()
    masks = (depth > 0).astype(np.float32)
    settings = dataclasses.replace(SMALL, refine="depth", refine_size=12, pose="estimate")
    scales = []
    for units in (1.0, 2.0):
        cams = tmp_path / f"rgbd{units}.npz"
        np.savez(cams, K=K, masks=masks, depth=depth * units)
        with pytest.raises(ValueError, match="--pose estimate"):
            input_views([photo], cams)
        views = input_views([photo], cams, pose_unknown=True)
        summary = reconstruct(sphere_predictor, [photo], BayesianKFusion(k=2), tmp_path / f"o{units}", settings, views)
        record = summary["refinement"]
        assert record["fallback"] is None and record["views"][0]["used"] == "depth"
        (group,) = record["pose"]["groups"]
        assert group["scale_std"] is not None  # the depth tells the size, from one view
        scales.append(group["scale"])
        camera = np.array(record["pose"]["cameras"][0])  # object units: the sphere's distance, whatever the units
        assert np.linalg.norm(camera[:3, 3]) == pytest.approx(np.linalg.norm(w2c[:3, 3]), rel=0.03)
    assert scales[0] == pytest.approx(1.0, rel=0.03)  # the depth was drawn at the decoder's own size
    assert scales[1] == pytest.approx(2.0 * scales[0], rel=1e-3)


def test_cli_camera_file_needs_refine(tiny_run, tmp_path, capsys):
    views = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[:1]
    np.savez(tmp_path / "cams.npz", K=np.eye(3)[None], world_to_cam=np.eye(4)[None])
    args = [*map(str, views), "--run", str(tiny_run["run"]), "--out", str(tmp_path / "o")]
    assert main([*args, "--cameras", str(tmp_path / "cams.npz")]) == 2
    assert "add --refine" in capsys.readouterr().err


def test_fit_refinement_stores_a_calibration_that_the_refinement_then_applies(tiny_run, sphere_predictor, tmp_path):
    from ushape.evaluation.refine_method import RefineMethod
    from ushape.recalibration.refine_information import SCALE_GRID, VIEW_EXPONENT_GRID, refined_sdf_temperature
    from ushape.recalibration.temperature import CALIBRATION_GRID
    from ushape.reconstruction.refine_calibration import (
        calibration_path,
        fit_and_store_refinement_calibration,
        read_refinement_calibration,
    )

    world = WorldIndex(tiny_run["world"], category="", splits={})
    points = np.random.default_rng(1).uniform(-1, 1, (300, 3))
    for shape_id in ("val_0", "val_1", "val_2"):  # a sphere a little larger than the decoder's at z = 0
        write_sdf(world, shape_id, np.concatenate([points, np.linalg.norm(points, axis=1, keepdims=True) - 0.55], 1))
    checkpoint = sphere_predictor.checkpoint
    try:
        record = fit_and_store_refinement_calibration(sphere_predictor, "masks", size=12, n_points=200)
        assert record["view_counts"] == [1, 3] and record["n_shapes"] == 3  # 3 views a shape: no 10
        assert record["information_scale"] in SCALE_GRID and record["sdf_temperature"] in CALIBRATION_GRID
        assert (
            record["sdf_view_exponent"] in VIEW_EXPONENT_GRID
            and record["seen"]["sdf_view_exponent"] in VIEW_EXPONENT_GRID
        )
        misfit = record["sdf_decoder_misfit"]
        assert misfit > 0 and record["sdf_floor"] in floor_grid(misfit)
        # T = 1 and no floor are on the grids: the fit is never worse on val than none.
        assert max(record["sdf_calibration_after"]) <= max(record["sdf_calibration_before"])
        assert record["latent_calibration_after"] <= record["latent_calibration_before"]
        seen = record["seen"]  # the floors where the views saw the sample and where they did not
        assert seen["floor_seen"] in floor_grid(misfit) and seen["floor_unseen"] in floor_grid(misfit)
        assert seen["floor_seen"] <= seen["floor_unseen"] and all(0 < f < 1 for f in seen["seen_fraction"])
        assert read_refinement_calibration(checkpoint, "masks") == record
        assert read_refinement_calibration(checkpoint, "depth") is None
        views = sorted((tiny_run["world"] / "renders" / "test_0").glob("*.png"))[:2]
        settings = dataclasses.replace(SMALL, refine="masks", refine_size=12)
        summary = reconstruct(sphere_predictor, views, BayesianKFusion(k=2), tmp_path / "out", settings)
        applied = summary["refinement"]["calibration"]
        assert applied["information_scale"] == record["information_scale"] and applied["size"] == 12
        # The mesh's std is drawn with the seen model: its factor at the 2 views refined on, its floors per vertex.
        assert summary["refinement"]["views_refined"] == 2 and summary["sdf_floor"] is None
        assert summary["sdf_temperature"] == pytest.approx(refined_sdf_temperature(seen, 2))
        assert applied["seen"] == seen and 0 < summary["refinement"]["seen_vertices"] < 1
        assert summary["mesh"]["std_mean"] >= seen["floor_seen"] * (1 - 1e-6)  # every vertex carries a floor
        run = type("Run", (), {"predictor": sphere_predictor})()
        method = RefineMethod("masks", size=12, calibrated=True)
        assert method.settings_for(run).information_scale == record["information_scale"]
        assert method.sdf_calibration_for(run) == (record["sdf_temperature"], record["sdf_floor"] or None)
        assert method.sdf_calibration_for(run, 3)[0] == pytest.approx(refined_sdf_temperature(record, 3))
        with pytest.raises(ValueError, match="--fit-refinement depth"):
            RefineMethod("depth", calibrated=True).settings_for(run)
        assert RefineMethod("depth").settings_for(run).information_scale == 1.0  # not calibrated: its own knobs
        with pytest.raises(ValueError, match="at least 1 val shape"):
            fit_and_store_refinement_calibration(sphere_predictor, "masks", n_shapes=0)
        assert read_refinement_calibration(checkpoint, "masks") == record  # the stored fit is kept
    finally:
        calibration_path(checkpoint).unlink(missing_ok=True)
        for shape_id in ("val_0", "val_1", "val_2"):
            world.sdf_path(shape_id).unlink()


def test_the_printed_pose_line_gives_the_scale_only_where_it_was_estimated():
    from ushape.reconstruction.cli import pose_outcome

    group = {"rotation_std_deg": 2.0, "translation_std": [0.01, 0.02, 0.05], "scale": 1.0, "scale_std": None}
    assert "scale" not in pose_outcome(group, 0) and "translation std 0.050" in pose_outcome(group, 0)
    ranged = {**group, "scale": 0.804, "scale_std": 0.118}  # a depth map or a baseline: the size is estimated
    assert pose_outcome(ranged, 0).endswith(", scale 0.804 (log std 0.118)")
