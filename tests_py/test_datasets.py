"""Dataset readers on tiny files written into the official folder layouts, ``+`` / ``*``, and the
DataLoader (batching, seeding, worker processes)."""

import os

import numpy as np
import pytest
from mipnet.data import (
    ETH3D,
    KITTI,
    ConcatDataset,
    CREStereo,
    DataLoader,
    Dataset,
    FolderPairs,
    MiddEval3,
    Middlebury2014,
    RepeatDataset,
    SceneFlow,
    SyntheticStereo,
    default_collate,
)
from mipnet.errors import FormatError, ShapeError
from mipnet.stereo.io import (
    write_crestereo_disparity,
    write_image,
    write_kitti_disparity,
    write_pfm,
)

H, W = 6, 8


def _rgb(value):
    return np.full((H, W, 3), value, np.uint8)


def _disp(base=3.0):
    return (base + np.arange(H * W, dtype=np.float32).reshape(H, W) / 8).astype(np.float32)


def _write_pair(left_path, right_path, value=10):
    for path, v in ((left_path, value), (right_path, value + 1)):
        os.makedirs(os.path.dirname(path), exist_ok=True)
        write_image(path, _rgb(v))


def _pfm(path, array):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    write_pfm(path, array)


def _check_sample(sample):
    assert sample["left"].shape == (H, W, 3) and sample["left"].dtype == np.uint8
    assert sample["right"].shape == (H, W, 3) and sample["right"].dtype == np.uint8
    assert sample["disparity"].shape == (H, W) and sample["disparity"].dtype == np.float32
    assert sample["valid"].shape == (H, W) and sample["valid"].dtype == bool
    assert np.all(sample["disparity"][~sample["valid"]] == 0)
    assert isinstance(sample["meta"], dict)


# ------------------------------------------------------------------------------- SceneFlow


def _sceneflow(root):
    ft = os.path.join(root, "FlyingThings3D")
    for split, letter, seq, frame in (("TRAIN", "A", "0000", "0006"), ("TRAIN", "B", "0001", "0007"),
                                      ("TEST", "A", "0002", "0008")):
        _write_pair(os.path.join(ft, "frames_cleanpass", split, letter, seq, "left", f"{frame}.png"),
                    os.path.join(ft, "frames_cleanpass", split, letter, seq, "right", f"{frame}.png"))
        disp = _disp()
        disp[0, 0] = 600.0  # |d| >= 512: invalid
        _pfm(os.path.join(ft, "disparity", split, letter, seq, "left", f"{frame}.pfm"), disp)
    mk = os.path.join(root, "Monkaa")
    _write_pair(os.path.join(mk, "frames_cleanpass", "treeflight", "left", "0000.png"),
                os.path.join(mk, "frames_cleanpass", "treeflight", "right", "0000.png"))
    _pfm(os.path.join(mk, "disparity", "treeflight", "left", "0000.pfm"), -_disp())  # sign: abs
    dr = os.path.join(root, "Driving")
    sub = ("35mm_focallength", "scene_forwards", "fast")
    _write_pair(os.path.join(dr, "frames_cleanpass", *sub, "left", "0001.png"),
                os.path.join(dr, "frames_cleanpass", *sub, "right", "0001.png"))
    _pfm(os.path.join(dr, "disparity", *sub, "left", "0001.pfm"), np.dstack([_disp()] * 3))


def test_sceneflow_layout(tmp_path):
    _sceneflow(str(tmp_path))
    train = SceneFlow(tmp_path)
    assert len(train) == 4
    for sample in train:
        _check_sample(sample)
        np.testing.assert_allclose(sample["disparity"][sample["valid"]], _disp()[sample["valid"]])
    first = train[0]
    assert not first["valid"][0, 0] and first["valid"].sum() == H * W - 1
    assert first["left"][0, 0, 0] == 10 and first["right"][0, 0, 0] == 11
    assert first["meta"]["disparity"].endswith(os.path.join("disparity", "TRAIN", "A", "0000", "left", "0006.pfm"))
    assert len(SceneFlow(tmp_path, split="TEST")) == 1
    assert len(SceneFlow(tmp_path, subsets=("Monkaa",))) == 1
    with pytest.raises(FileNotFoundError):
        SceneFlow(tmp_path, dstype="frames_finalpass")
    with pytest.raises(ValueError):
        SceneFlow(tmp_path, subsets=("Sintel",))


# ------------------------------------------------------------------------------ Middlebury


def test_middlebury2014_layout(tmp_path):
    scene = tmp_path / "Adirondack-perfect"
    _write_pair(str(scene / "im0.png"), str(scene / "im1.png"))
    write_image(scene / "im1E.png", _rgb(99))
    disp = _disp()
    disp[1, 2] = np.inf
    _pfm(str(scene / "disp0.pfm"), disp)
    (scene / "calib.txt").write_text("cam0=[10 0 4; 0 10 3; 0 0 1]\nbaseline=100\n")
    (tmp_path / "notes.txt").write_text("not a scene")
    data = Middlebury2014(tmp_path)
    assert len(data) == 1
    sample = data[0]
    _check_sample(sample)
    assert not sample["valid"][1, 2] and sample["valid"].sum() == H * W - 1
    assert sample["meta"]["calib"].endswith("calib.txt")
    assert Middlebury2014(tmp_path, right_image="im1E")[0]["right"][0, 0, 0] == 99


def _mask(path):
    mask = np.full((H, W), 255, np.uint8)
    mask[0, :3] = 128  # occluded
    mask[5, 7] = 0  # no ground truth
    write_image(path, mask)


def test_middeval3_layout_and_noc_mask(tmp_path):
    for scene in ("Motorcycle", "Adirondack"):
        folder = tmp_path / "trainingH" / scene
        _write_pair(str(folder / "im0.png"), str(folder / "im1.png"))
        disp = _disp()
        disp[5, 7] = np.inf
        _pfm(str(folder / "disp0GT.pfm"), disp)
        _mask(folder / "mask0nocc.png")
    _write_pair(str(tmp_path / "testH" / "Australia" / "im0.png"), str(tmp_path / "testH" / "Australia" / "im1.png"))

    data = MiddEval3(tmp_path)
    assert len(data) == 2 and data[0]["meta"]["left"].endswith(os.path.join("Adirondack", "im0.png"))
    _check_sample(data[0])
    assert data[0]["valid"].sum() == H * W - 1
    noc = MiddEval3(tmp_path, occ=False)[0]
    assert noc["valid"].sum() == H * W - 4 and not noc["valid"][0, :3].any()

    test = MiddEval3(tmp_path, split="test")[0]
    _check_sample(test)
    assert not test["valid"].any() and test["meta"]["has_gt"] is False
    with pytest.raises(FileNotFoundError):
        MiddEval3(tmp_path, resolution="F")


# ----------------------------------------------------------------------------------- ETH3D


def test_eth3d_layout_gray_images(tmp_path):
    scene = tmp_path / "two_view_training" / "delivery_area_1l"
    scene.mkdir(parents=True)
    write_image(scene / "im0.png", np.full((H, W), 40, np.uint8))
    write_image(scene / "im1.png", np.full((H, W), 41, np.uint8))
    gt = tmp_path / "two_view_training_gt" / "delivery_area_1l"
    disp = _disp()
    disp[2, 2] = np.inf
    _pfm(str(gt / "disp0GT.pfm"), disp)
    _mask(gt / "mask0nocc.png")
    sample = ETH3D(tmp_path)[0]
    _check_sample(sample)
    assert (sample["left"] == 40).all()
    assert sample["valid"].sum() == H * W - 1
    assert ETH3D(tmp_path, occ=False)[0]["valid"].sum() == H * W - 5
    os.remove(gt / "mask0nocc.png")
    with pytest.raises(FileNotFoundError, match="mask0nocc"):
        ETH3D(tmp_path, occ=False)


# ----------------------------------------------------------------------------------- KITTI


@pytest.mark.parametrize("year, folders", [(2015, ("image_2", "image_3", "disp_occ_0", "disp_noc_0")),
                                           (2012, ("colored_0", "colored_1", "disp_occ", "disp_noc"))])
def test_kitti_layouts(tmp_path, year, folders):
    left_dir, right_dir, occ_dir, noc_dir = (tmp_path / "training" / f for f in folders)
    for frame in ("000000", "000001"):
        _write_pair(str(left_dir / f"{frame}_10.png"), str(right_dir / f"{frame}_10.png"))
        write_image(left_dir / f"{frame}_11.png", _rgb(0))  # next time step: not a pair
        disp = _disp()
        disp[:, 0] = 0  # no ground truth
        occ_dir.mkdir(exist_ok=True)
        noc_dir.mkdir(exist_ok=True)
        write_kitti_disparity(occ_dir / f"{frame}_10.png", disp)
        disp[:, 1] = 0
        write_kitti_disparity(noc_dir / f"{frame}_10.png", disp)
    data = KITTI(tmp_path, year=year)
    assert len(data) == 2
    sample = data[1]
    _check_sample(sample)
    assert sample["valid"].sum() == H * (W - 1)
    np.testing.assert_allclose(sample["disparity"][sample["valid"]], _disp()[sample["valid"]], atol=1 / 512)
    assert KITTI(tmp_path, year=year, occ=False)[0]["valid"].sum() == H * (W - 2)


def test_kitti_mislabelled_disparity_names_the_file(tmp_path):
    _write_pair(str(tmp_path / "training" / "image_2" / "000000_10.png"),
                str(tmp_path / "training" / "image_3" / "000000_10.png"))
    (tmp_path / "training" / "disp_occ_0").mkdir()
    write_image(tmp_path / "training" / "disp_occ_0" / "000000_10.png", np.zeros((H, W), np.uint8))
    with pytest.raises(FormatError, match="disp_occ_0"):
        KITTI(tmp_path)[0]


# ------------------------------------------------------------------------- CREStereo, folders


def test_crestereo_layout(tmp_path):
    for sub in ("tree", "shapenet"):
        folder = tmp_path / sub
        folder.mkdir()
        write_image(folder / "0001_left.jpg", _rgb(100))
        write_image(folder / "0001_right.jpg", _rgb(100))
        disp = _disp()
        disp[3, 3] = np.inf
        write_crestereo_disparity(folder / "0001_left.disp.png", disp)
        write_crestereo_disparity(folder / "0001_right.disp.png", disp)
    data = CREStereo(tmp_path)
    assert len(data) == 2
    sample = data[0]
    _check_sample(sample)
    assert sample["valid"].sum() == H * W - 1
    np.testing.assert_allclose(sample["disparity"][sample["valid"]], _disp()[sample["valid"]], atol=1 / 64)


@pytest.mark.parametrize("fmt", ["pfm", "npy", "kitti"])
def test_folder_pairs(tmp_path, fmt):
    for i in range(3):
        _write_pair(str(tmp_path / "L" / f"{i}.png"), str(tmp_path / "R" / f"{i}.png"), value=i)
        disp = _disp(base=i + 1)
        disp[0, 0] = np.inf if fmt != "kitti" else 0
        if fmt == "pfm":
            write_pfm(tmp_path / "L" / f"{i}.pfm", disp)
        elif fmt == "npy":
            np.save(tmp_path / "L" / f"{i}.npy", disp)
        else:
            (tmp_path / "D").mkdir(exist_ok=True)
            write_kitti_disparity(tmp_path / "D" / f"{i}.png", disp)
    disp_glob = str(tmp_path / ("D" if fmt == "kitti" else "L") / f"*.{'png' if fmt == 'kitti' else fmt}")
    data = FolderPairs(str(tmp_path / "L" / "*.png"), str(tmp_path / "R" / "*.png"), disp_glob)
    assert len(data) == 3
    sample = data[2]
    _check_sample(sample)
    assert sample["left"][0, 0, 0] == 2 and not sample["valid"][0, 0]
    np.testing.assert_allclose(sample["disparity"][1], _disp(base=3)[1], atol=1 / 512)


def test_folder_pairs_without_gt_and_mismatch(tmp_path):
    for i in range(2):
        _write_pair(str(tmp_path / "L" / f"{i}.png"), str(tmp_path / "R" / f"{i}.png"))
    data = FolderPairs(str(tmp_path / "L" / "*.png"), str(tmp_path / "R" / "*.png"))
    assert not data[0]["valid"].any() and data[0]["meta"]["has_gt"] is False
    os.remove(tmp_path / "R" / "1.png")
    with pytest.raises(ValueError, match="pair up"):
        FolderPairs(str(tmp_path / "L" / "*.png"), str(tmp_path / "R" / "*.png"))


def test_corrupt_pfm_in_dataset_names_the_file(tmp_path):
    scene = tmp_path / "trainingH" / "Piano"
    _write_pair(str(scene / "im0.png"), str(scene / "im1.png"))
    (scene / "disp0GT.pfm").write_bytes(b"Pf\n8 6\n-1\n" + b"\0" * 10)
    with pytest.raises(FormatError, match="disp0GT.pfm"):
        MiddEval3(tmp_path)[0]


# ------------------------------------------------------------------------ combining datasets


class _Numbers(Dataset):
    """Sample i holds i in every field; cheap for loader tests."""

    def __init__(self, n, offset=0):
        self.n, self.offset = n, offset

    def __len__(self):
        return self.n

    def __getitem__(self, index):
        index = self._check_index(index)
        value = index + self.offset
        return {"x": np.full((2, 3), value, np.float32), "i": value, "meta": {"id": value}}


def test_concat_and_repeat():
    a, b = _Numbers(3), _Numbers(2, offset=100)
    both = a + b
    assert isinstance(both, ConcatDataset) and len(both) == 5
    assert [both[i]["i"] for i in range(5)] == [0, 1, 2, 100, 101]
    assert both[-1]["i"] == 101
    with pytest.raises(IndexError):
        both[5]
    assert len((a + b) + a) == 8 and len(((a + b) + a).datasets) == 3  # flattened
    repeated = 3 * b
    assert isinstance(repeated, RepeatDataset) and len(repeated) == 6
    assert [repeated[i]["i"] for i in range(6)] == [100, 101] * 3
    assert len(b * 2 + a) == 7
    assert len(RepeatDataset(a, 0)) == 0
    with pytest.raises(TypeError):
        a * 1.5


# ------------------------------------------------------------------------------ DataLoader


def test_loader_batches_and_drop_last():
    loader = DataLoader(_Numbers(5), batch_size=2)
    batches = list(loader)
    assert len(loader) == 3 and [b["x"].shape for b in batches] == [(2, 2, 3), (2, 2, 3), (1, 2, 3)]
    np.testing.assert_array_equal(batches[0]["i"], [0, 1])
    assert batches[2]["meta"] == [{"id": 4}]
    assert len(DataLoader(_Numbers(5), batch_size=2, drop_last=True)) == 2
    assert len(list(DataLoader(_Numbers(5), batch_size=2, drop_last=True))) == 2


def _order(loader):
    return [int(i) for batch in loader for i in batch["i"]]


def test_loader_shuffle_is_seeded_and_changes_per_epoch():
    a = DataLoader(_Numbers(20), batch_size=4, shuffle=True, seed=7)
    b = DataLoader(_Numbers(20), batch_size=4, shuffle=True, seed=7)
    first, second = _order(a), _order(a)
    assert sorted(first) == list(range(20)) and first != list(range(20))
    assert first != second  # a new epoch, a new order
    assert _order(b) == first and _order(b) == second
    assert _order(DataLoader(_Numbers(20), batch_size=4, shuffle=True, seed=8)) != first
    b.set_epoch(1)
    assert _order(b) == second


def _jitter(sample, rng):
    return dict(sample, x=sample["x"] + rng.random(), pid=os.getpid())


def test_loader_workers_match_single_process():
    data = _Numbers(11)
    kwargs = dict(batch_size=3, shuffle=True, seed=3, transform=_jitter)
    single = list(DataLoader(data, num_workers=0, **kwargs))
    multi = list(DataLoader(data, num_workers=2, **kwargs))
    assert len(single) == len(multi) == 4
    for s, m in zip(single, multi):
        np.testing.assert_array_equal(s["i"], m["i"])
        np.testing.assert_array_equal(s["x"], m["x"])
    assert all(pid == os.getpid() for batch in single for pid in batch["pid"])
    assert all(pid != os.getpid() for batch in multi for pid in batch["pid"])


def test_loader_workers_on_synthetic_data_and_early_break():
    data = SyntheticStereo(4, 24, 32, seed=1)
    single = list(DataLoader(data, batch_size=2, num_workers=0))
    multi = list(DataLoader(data, batch_size=2, num_workers=2))
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(single[1][key], multi[1][key])
    assert single[0]["left"].shape == (2, 24, 32, 3)
    for _batch in DataLoader(data, batch_size=1, num_workers=2):
        break  # the pool is torn down when the generator is closed


def test_loader_survives_a_killed_worker():
    # `kill` of a process group reaches the workers too; the loader must neither hang nor go on silently.
    import multiprocessing
    import signal
    import threading

    batches = iter(DataLoader(SyntheticStereo(8, 24, 32, seed=1), batch_size=1, num_workers=1))
    next(batches)
    for child in multiprocessing.active_children():
        os.kill(child.pid, signal.SIGTERM)
    outcome = []

    def drain():
        try:
            outcome.append(len(list(batches)))
        except RuntimeError as exc:
            outcome.append(exc)

    thread = threading.Thread(target=drain, daemon=True)
    thread.start()
    thread.join(60)
    assert outcome, "the loader hung after its worker was killed"
    assert isinstance(outcome[0], RuntimeError) and "worker process died" in str(outcome[0])


def test_collate_shape_mismatch_is_clear():
    with pytest.raises(ShapeError, match="batch_size=1"):
        default_collate([{"x": np.zeros((2, 2))}, {"x": np.zeros((3, 2))}])


def test_loader_argument_checks():
    with pytest.raises(ValueError):
        DataLoader(_Numbers(2), batch_size=0)
    with pytest.raises(ValueError):
        DataLoader(_Numbers(2), num_workers=-1)
