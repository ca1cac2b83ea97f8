"""The ViTPose and HMR 2.0 estimators: the thesis's patch preprocessing they share (invariants and geometry), the
estimators on random weights saved in the official layouts, and `m3c run --checkpoints DIR` end to end on the
bundled clip with those files and a random dpvo.pth (the results are meaningless, the plumbing is real)."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from m3c.models.dpvo import DPVO_SOURCE, DPVONet
from m3c.models.hmr2 import HMR2, DecoderConfig
from m3c.models.vit import ViTConfig
from m3c.models.vitpose import ViTPose
from m3c.perception import FrameContext, Person, create
from m3c.perception.boxes import network_input, process_box
from m3c.perception.mediapipe_pose import mediapipe_available

pytestmark = pytest.mark.usefixtures("one_torch_thread")

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
# Width 384 is ViTPose-S's (an official width, so the loaders know its heads); one block keeps it fast.
TINY_VIT = ViTConfig(embed_dim=384, depth=1, num_heads=12)


def test_patch_holds_the_whole_box_and_maps_back(rng):
    frame = np.zeros((300, 400, 3), dtype=np.uint8)
    for box in ([50.0, 40.0, 110.0, 250.0], [0.0, 0.0, 30.0, 120.0], [350.0, 100.0, 400.0, 300.0]):
        for size in ((256, 192), (256, 256)):
            net = network_input(frame, box, size=size)
            assert net.image.shape == size + (3,)
            square = process_box(box, frame.shape[:2], 5.0)
            # The input spans the whole (padded, squared, shifted) patch, so it holds the whole box.
            assert (net.region[:2] <= square[:2] - 0.5 + 1e-9).all()
            assert (net.region[2:] >= square[2:] - 0.5 - 1e-9).all()
            assert net.region[2] - net.region[0] == pytest.approx((net.region[3] - net.region[1]) * size[1] / size[0])
    # A marked frame pixel lands where origin + scale * input says (bilinear sampling of one bright pixel).
    frame[120, 80] = (0, 255, 0)  # green, unlike the white margin
    net = network_input(frame, [50.0, 40.0, 110.0, 250.0], size=(256, 192))
    green = net.image[..., 1].astype(float) - net.image[..., 0]
    j, i = np.unravel_index(np.argmax(green), green.shape)
    np.testing.assert_allclose(net.origin + net.scale * np.array([i, j]), [80, 120], atol=0.6 * net.scale.max())


def test_patch_whitens_others_but_not_the_persons_mask():
    frame = np.full((200, 300, 3), 40, dtype=np.uint8)
    me = np.array([100.0, 20.0, 160.0, 180.0])
    other = np.array([140.0, 30.0, 220.0, 190.0])  # overlaps my box
    mask = np.zeros((200, 300), dtype=bool)
    mask[20:180, 100:150] = True  # my silhouette, partly inside the other's box
    person = Person(me, 1.0, mask=mask, mask_box=np.array([0, 0, 300, 200]))
    net = network_input(frame, me, [other], person.mask_in, size=(256, 256))
    # Back-map every input pixel to the frame: inside my mask nothing is whitened, inside the other's box (outside
    # my mask) everything is; the margin outside the frame-cut patch is white too.
    jj, ii = np.mgrid[0:256, 0:256]
    u = net.origin[0] + net.scale[0] * ii
    v = net.origin[1] + net.scale[1] * jj
    mine = (u > 101) & (u < 148) & (v > 22) & (v < 178)
    theirs = (u > 151) & (u < 219) & (v > 32) & (v < 188)
    assert (net.image[mine] == 40).all()
    assert (net.image[theirs] == 255).all()
    assert (net.image[~mine & ~theirs & (u > 60) & (u < 130) & (v > 17) & (v < 183)] == 40).all()


def tiny_vitpose(path: Path) -> None:
    torch.manual_seed(0)
    model = ViTPose(TINY_VIT)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"meta": {}, "state_dict": model.state_dict()}, path)


def tiny_hmr2(path: Path) -> None:
    torch.manual_seed(1)
    decoder = DecoderConfig(dim=64, depth=1, heads=2, dim_head=32, mlp_dim=64, context_dim=384)
    model = HMR2(TINY_VIT, decoder)
    with torch.no_grad():  # small readout: poses and cameras near the mean, as a trained model's would be
        for layer in (model.smpl_head.decpose, model.smpl_head.decshape, model.smpl_head.deccam):
            layer.weight.mul_(0.01)
            layer.bias.zero_()
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"state_dict": {**model.state_dict(), "smpl.betas": torch.zeros(1, 10)}}, path)
    config = {"MODEL": {"SMPL_HEAD": {"TYPE": "transformer_decoder", "TRANSFORMER_DECODER": {
        "depth": 1, "heads": 2, "dim_head": 32, "mlp_dim": 64, "context_dim": 384}}}}
    (path.parent.parent / "model_config.yaml").write_text(yaml.safe_dump(config))


@pytest.fixture(scope="module")
def models_dir(tmp_path_factory):
    from m3c.models.hmr2 import HMR2_SOURCE
    from m3c.models.vitpose import VITPOSE_SOURCE

    root = tmp_path_factory.mktemp("models")
    tiny_vitpose(root / VITPOSE_SOURCE.default_path)
    tiny_hmr2(root / HMR2_SOURCE.default_path)
    torch.manual_seed(2)
    (root / DPVO_SOURCE.default_path).parent.mkdir(parents=True)
    torch.save({"module." + k: v for k, v in DPVONet().state_dict().items()}, root / DPVO_SOURCE.default_path)
    return root


def test_estimators_on_two_people(models_dir, synthetic_body_model):
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    ctx = FrameContext(image, 0)
    people = [Person([40.0, 30.0, 120.0, 220.0], 0.9), Person([150.0, 20.0, 230.0, 230.0], 0.8)]
    pose2d = create("pose2d", "vitpose", {"checkpoint": str(models_dir / "vitpose/vitpose-h.pth")})
    found = pose2d.estimate(ctx, people)
    for person, out in zip(people, found):
        assert out.keypoints.shape == (17, 3) and out.sources["pose2d"] == "vitpose"
        region = network_input(image, person.box, [p.box for p in people if p is not person], size=(256, 192))
        assert (out.keypoints[:, :2] >= region.region[:2] - 1).all()
        assert (out.keypoints[:, :2] <= region.region[2:] + 1).all()
        assert ((out.keypoints[:, 2] >= 0) & (out.keypoints[:, 2] <= 1)).all()
    # A tracker's wide proposal with the person's mask comes back as the mask's tight box (its pixels' outer edges).
    mask = np.zeros((240, 320), dtype=bool)
    mask[50:200, 60:100] = True
    wide = Person([30.0, 20.0, 140.0, 230.0], 0.0, mask=mask, mask_box=np.array([0, 0, 320, 240]))
    strict = create("pose2d", "vitpose", {"checkpoint": str(models_dir / "vitpose/vitpose-h.pth"),
                                          "min_confidence": 1.01})
    np.testing.assert_array_equal(strict.estimate(ctx, [wide])[0].box, [59.5, 49.5, 99.5, 199.5])
    body = create("body", "hmr2", {"checkpoint": str(models_dir / "hmr2/checkpoints/epoch=35-step=1000000.ckpt")})
    assert body.reads_images
    observed = body.observe(ctx, found)
    assert len(observed) == 2
    keypoints = found[0].keypoints.copy()
    keypoints[:, 2] = 1.0  # seen (random weights give low confidences)
    fits = body.fit_track(keypoints[None], None, np.array([300.0, 300.0, 160.0, 120.0]), observations=[observed[0]])
    assert fits.status == ["ok"] and fits.pose.shape == (1, 24, 3)
    # The body's translation puts its origin where the crop camera does (CLIFF), in front of the camera.
    s, tx, ty = observed[0]["crop_cam"]
    r = observed[0]["region"]
    u = 300 * fits.transl[0, 0] / fits.transl[0, 2] + 160
    assert u == pytest.approx((r[0] + r[2]) / 2 + (r[2] - r[0]) * s * tx / 2, rel=1e-9)
    assert fits.transl[0, 2] > 0 and np.isfinite(fits.reprojection_error_px).all() and fits.num_keypoints[0] == 17
    flipped = dict(observed[0], crop_cam=-observed[0]["crop_cam"])  # scale < 0: behind the camera
    fits = body.fit_track(keypoints[None], None, np.array([300.0, 300.0, 160.0, 120.0]), observations=[flipped])
    assert fits.status == ["bad_camera"] and not fits.valid.any() and np.isnan(fits.reprojection_error_px).all()
    pose2d.close()
    body.close()


@pytest.mark.slow
@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (pip install 'm3c[perception]') to detect")
def test_run_picks_up_the_networks_from_checkpoints(models_dir, tmp_path):
    from m3c.cli import main

    out = tmp_path / "out"
    code = main(["run", str(EXAMPLE), "--out", str(out), "--frames", "0:12", "--checkpoints", str(models_dir),
                 "--set", "optimize.enabled=false", "--set", "perception.options={detect_every: 1}",
                 "--set", "local_tracks.min_visible_frames=3", "--set", "vo.options={max_image_side: 192, patches_per_frame: 16}",
                 "--set", "vo.dpvo_iterations=1",
                 "--until", "results", "--no-progress", "-q"])
    assert code == 0
    summary = json.loads((out / "results.json").read_text())
    assert summary["backends"]["vo"]["method"] == "dpvo"
    estimators = summary["backends"]["perception"]["estimators"]
    assert estimators["pose2d"]["name"] == "vitpose" and estimators["body"]["name"] == "hmr2"
    assert estimators["pose2d"]["options"]["checkpoint"].endswith("vitpose/vitpose-h.pth")
    arrays = np.load(out / "results.npz")
    assert arrays["cam_transl"].shape[1] == 12 and np.isfinite(arrays["cam_transl"][arrays["valid"]]).all()


@pytest.mark.parametrize("setting,named", [("vo.method=dpvo", "DPVO"), ("perception.estimators={pose2d: vitpose}",
                                                                        "ViTPose"),
                                           ("perception.estimators={body: hmr2}", "HMR 2.0")])
def test_a_named_network_without_its_file_is_reported(tmp_path, capsys, setting, named):
    from m3c.cli import main

    empty = tmp_path / "models"
    empty.mkdir()
    code = main(["run", str(EXAMPLE), "--out", str(tmp_path / "out"), "--frames", "0:4", "--checkpoints", str(empty),
                 "--set", setting, "--no-progress", "-q"])
    err = capsys.readouterr().err
    assert code == 3, err
    assert named in err and str(empty) in err
