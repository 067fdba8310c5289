"""Trajectory files: TUM, KITTI and EuRoC reading, writing, sniffing and strict errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slamcli.errors import ExportError, FormatError, InputError, UnknownFormatError
from slamcli.formats.trajectory import (
    read_poses,
    read_trajectory,
    sniff_trajectory_format,
    write_kitti,
    write_trajectory,
    write_tum,
)
from slamcli.geometry import make_pose, rotation_angle, so3_exp
from slamcli.types import Trajectory


def _random_trajectory(n: int = 50, seed: int = 3) -> Trajectory:
    rng = np.random.default_rng(seed)
    # Sub-microsecond stamps that float64 seconds could not hold exactly.
    stamps = 1_305_031_102_160_407_123 + np.cumsum(rng.integers(1, 40_000_000, n))
    rot = so3_exp(rng.normal(size=(n, 3)) * 2.0)
    trans = rng.normal(size=(n, 3)) * 50.0
    return Trajectory(stamps.astype(np.int64), make_pose(rot, trans))


def _write(path: Path, text: str) -> Path:
    path.write_bytes(text.encode())
    return path


def test_tum_round_trip_keeps_nanoseconds(tmp_path: Path) -> None:
    traj = _random_trajectory()
    path = write_tum(tmp_path / "t.txt", traj)
    back = read_trajectory(path)
    np.testing.assert_array_equal(back.stamps_ns, traj.stamps_ns)
    np.testing.assert_allclose(back.world_from_body, traj.world_from_body, rtol=0, atol=2e-9)
    first = path.read_text().splitlines()[1].split()[0]
    assert first == f"{traj.stamps_ns[0] // 10**9}.{traj.stamps_ns[0] % 10**9:09d}"


def test_tum_stamps_keep_nine_decimals_even_when_round(tmp_path: Path) -> None:
    traj = Trajectory(np.array([1_000_000_000, 2_500_000_000]), np.stack([np.eye(4)] * 2))
    text = write_tum(tmp_path / "r.txt", traj).read_text()
    assert [ln.split()[0] for ln in text.splitlines()[1:]] == ["1.000000000", "2.500000000"]


def test_kitti_round_trip_with_times(tmp_path: Path) -> None:
    traj = _random_trajectory(seed=5)
    write_kitti(tmp_path / "k.txt", traj, times=tmp_path / "times.txt")
    back = read_trajectory(tmp_path / "k.txt", "kitti", times=tmp_path / "times.txt")
    np.testing.assert_array_equal(back.stamps_ns, traj.stamps_ns)
    np.testing.assert_allclose(back.world_from_body, traj.world_from_body, rtol=1e-12, atol=1e-12)


def test_kitti_without_times_uses_the_frame_index_in_seconds(tmp_path: Path) -> None:
    traj = _random_trajectory(n=4)
    write_trajectory(tmp_path / "k.txt", traj, "kitti")
    table = read_poses(tmp_path / "k.txt")
    assert table.format == "kitti" and not table.timed
    np.testing.assert_array_equal(table.stamps_ns, [0, 10**9, 2 * 10**9, 3 * 10**9])


def test_writers_are_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "t.txt"
    path.write_text("previous\n")

    def fail(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(Path, "write_text", fail)
    with pytest.raises(OSError, match="disk full"):
        write_tum(path, _random_trajectory(n=3))
    monkeypatch.undo()
    assert path.read_text() == "previous\n"
    assert [p.name for p in tmp_path.iterdir()] == ["t.txt"]
    with pytest.raises(ExportError, match="does not exist"):
        write_tum(tmp_path / "missing" / "t.txt", _random_trajectory(n=3))


def test_tum_reads_comments_crlf_and_four_decimal_quaternions(tmp_path: Path) -> None:
    path = _write(
        tmp_path / "q.txt",
        "# timestamp tx ty tz qx qy qz qw\r\n\r\n"
        "1305031098.6659 1.0 2.0 3.0 0.0 0.0 0.7071 0.7071\r\n"
        "1305031098.6759 1.0 2.0 3.0 0.0 0.0 0.0 1.0\r\n",
    )
    traj = read_trajectory(path)
    assert traj.stamps_ns.tolist() == [1_305_031_098_665_900_000, 1_305_031_098_675_900_000]
    rot = traj.world_from_body[0, :3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    assert np.rad2deg(rotation_angle(rot)) == pytest.approx(90.0, abs=1e-9)
    np.testing.assert_allclose(traj.world_from_body[0, :3, 3], [1.0, 2.0, 3.0])


def test_euroc_reads_ns_stamps_and_wxyz(tmp_path: Path) -> None:
    header = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
    header += "q_RS_y [], q_RS_z [], v_x\n"
    path = _write(
        tmp_path / "data.csv",
        header + "1403715524907143168,0.5,1.5,0.9,0.7071068,0,0,0.7071068,0.1\n"
        "1403715524912143104,0.6,1.5,0.9,1,0,0,0,0.1\n",
    )
    assert sniff_trajectory_format(path) == "euroc"
    traj = read_trajectory(path)
    assert traj.stamps_ns.tolist() == [1403715524907143168, 1403715524912143104]
    # w first: a 90 degree turn about z, not about x.
    np.testing.assert_allclose(traj.world_from_body[0, :3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-6)


def test_real_files(trajectories_dir: Path) -> None:
    d = trajectories_dir
    fr2 = read_poses(d / "fr2_desk_groundtruth.txt")
    assert (fr2.format, len(fr2)) == ("tum", 20957)
    # TUM's own ground truth repeats one stamp; read_poses keeps both rows.
    assert fr2.repeated().size == 1 and int(fr2.lines[fr2.repeated()[0]]) == 10863
    assert len(fr2.to_trajectory()) == 20956
    orb = read_poses(d / "fr2_desk_ORB.txt")
    assert orb.stamps_ns[0] == 1_311_868_164_363_181_000
    v102 = read_poses(d / "V102.txt")
    assert v102.repeated().size == 4 and int(v102.lines[v102.repeated()[0]]) == 433
    euroc = read_poses(d / "V102_groundtruth.csv")
    assert (euroc.format, len(euroc), int(euroc.stamps_ns[0])) == (
        "euroc",
        16702,
        1403715524907143168,
    )
    kitti = read_poses(d / "KITTI_00_gt.txt", times=d / "KITTI_00_gt_times.txt")
    assert kitti.format == "kitti" and kitti.timed and len(kitti) == 4541
    assert kitti.stamps_ns[1] == 103_735_900
    assert sniff_trajectory_format(d / "KITTI_00_SPTAM.txt") == "kitti"


def test_duplicate_policies(tmp_path: Path) -> None:
    path = _write(
        tmp_path / "d.txt",
        "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n2.0 2 0 0 0 0 0 1\n3.0 3 0 0 0 0 0 1\n",
    )
    assert len(read_poses(path)) == 4
    assert read_trajectory(path).positions[:, 0].tolist() == [0, 1, 3]
    assert read_trajectory(path, duplicates="last").positions[:, 0].tolist() == [0, 2, 3]
    with pytest.raises(FormatError, match=r"d\.txt:3: timestamp 2\.000000000 s repeats"):
        read_trajectory(path, duplicates="error")


MALFORMED = {
    "columns": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n3.0 0 0 0 0 0 1\n", "expected 8 columns"),
    "not a number": ("1.0 0 0 0 0 0 0 1\n\n3.0 0 0 x 0 0 0 1\n", "column 4: value 'x'"),
    "nan": ("# c\n1.0 0 0 0 0 0 0 1\n3.0 0 nan 0 0 0 0 1\n", "not finite"),
    "inf": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n3.0 0 0 0 0 0 0 inf\n", "not finite"),
    "quaternion": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n3.0 0 0 0 0 0 0.2 1.1\n", "norm is"),
    "zero quaternion": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n3.0 0 0 0 0 0 0 0\n", "norm is 0"),
    "backwards": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n1.5 0 0 0 0 0 0 1\n", "backwards"),
    "stamp": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n12:30 0 0 0 0 0 0 1\n", "timestamp '12:30'"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_tum(tmp_path: Path, case: str) -> None:
    text, what = MALFORMED[case]
    path = _write(tmp_path / "file.txt", text)
    with pytest.raises(FormatError, match=r"file\.txt:3: ") as info:
        read_poses(path, "tum")
    assert what in str(info.value)


@pytest.mark.parametrize("text", ["", "# only a comment\n\n"])
def test_empty_file_names_the_file(tmp_path: Path, text: str) -> None:
    path = _write(tmp_path / "empty.txt", text)
    with pytest.raises(FormatError, match=r"empty\.txt: no poses"):
        read_poses(path)
    with pytest.raises(FormatError, match=r"empty\.txt: no poses"):
        read_poses(path, "tum")


def _kitti_row(rot: np.ndarray, t: float = 0.0) -> str:
    pose = make_pose(rot, [t, 0.0, t])
    return " ".join(f"{v:.9f}" for v in pose[:3, :].ravel())


def test_kitti_rotation_must_be_orthonormal(tmp_path: Path) -> None:
    good = _kitti_row(np.eye(3))
    stretched = _kitti_row(np.diag([1.01, 1.0, 1.0]))
    with pytest.raises(FormatError, match=r"k\.txt:3: rotation is not orthonormal"):
        read_poses(_write(tmp_path / "k.txt", f"{good}\n{good}\n{stretched}\n"), "kitti")
    mirrored = _kitti_row(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(FormatError, match=r"m\.txt:2: .*det = -1"):
        read_poses(_write(tmp_path / "m.txt", f"{good}\n{mirrored}\n"))


def test_kitti_times_file_errors(tmp_path: Path) -> None:
    row = _kitti_row(np.eye(3))
    poses = _write(tmp_path / "k.txt", f"{row}\n{row}\n{row}\n")
    short = _write(tmp_path / "times.txt", "0.0\n0.1\n")
    with pytest.raises(FormatError, match=r"times\.txt: has 2 times but .*k\.txt has 3 poses"):
        read_poses(poses, times=short)
    backwards = _write(tmp_path / "back.txt", "0.0\n0.2\n0.1\n")
    with pytest.raises(FormatError, match=r"back\.txt:3: time goes backwards"):
        read_poses(poses, times=backwards)
    with pytest.raises(InputError, match="only goes with KITTI"):
        read_poses(_write(tmp_path / "t.txt", "1.0 0 0 0 0 0 0 1\n"), times=short)


def test_euroc_errors(tmp_path: Path) -> None:
    head = "#timestamp,x,y,z,qw,qx,qy,qz\n"
    ok = "1403715524907143168,0,0,0,1,0,0,0\n"
    with pytest.raises(FormatError, match=r"e\.csv:3: timestamp '1403715524\.9' is not an integer"):
        read_poses(_write(tmp_path / "e.csv", head + ok + "1403715524.9,0,0,0,1,0,0,0\n"), "euroc")
    with pytest.raises(FormatError, match=r"f\.csv:2: expected at least 8"):
        read_poses(_write(tmp_path / "f.csv", head + "1403715524907143168,0,0,0,1\n"), "euroc")
    with pytest.raises(FormatError, match=r"g\.csv:3: expected 8 columns"):
        read_poses(_write(tmp_path / "g.csv", head + ok + ok.strip() + ",7\n"), "euroc")


def test_sniffing(tmp_path: Path) -> None:
    assert sniff_trajectory_format(_write(tmp_path / "a.txt", "# x\n1 0 0 0 0 0 0 1\n")) == "tum"
    with pytest.raises(UnknownFormatError, match="5 columns"):
        sniff_trajectory_format(_write(tmp_path / "b.txt", "1 2 3 4 5\n"))
    with pytest.raises(UnknownFormatError, match="not a nanosecond"):
        sniff_trajectory_format(_write(tmp_path / "c.csv", "1.5,0,0,0,1,0,0,0\n"))
    with pytest.raises(InputError, match="no such file"):
        read_poses(tmp_path / "missing.txt")
