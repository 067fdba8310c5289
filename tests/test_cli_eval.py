"""``slamcli eval``: figures equal evo 1.38's on the evo reference trajectories, and clean errors.

The reference figures below were produced once with evo 1.38.0 in a separate environment, by
the commands in the comments, run in ../shared/data/trajectories, and read at full precision
from their ``--save_results`` archives (stats.json; the scale is the cube root of the
determinant of alignment_transformation_sim3).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app

runner = CliRunner()

REL = 1e-6

EVO_REFERENCE: dict[str, dict[str, Any]] = {
    # evo_ape tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt --align
    # evo_rpe tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt --align --delta 1 --delta_unit f
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "fr2_desk_orb_se3": {
        "args": ["fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", "--rpe-delta", "1"],
        "pairs": 2174,
        "scale": 1.0,
        "ate": {
            "rmse": 0.008118977562045396,
            "mean": 0.007491776870216619,
            "median": 0.0074146298293173854,
            "std": 0.0031290695070394156,
            "min": 0.00034963619840638655,
            "max": 0.024299593694385224,
            "sse": 0.14330528992361463,
        },
        "rpe_trans": {
            "rmse": 0.003490321374787296,
            "mean": 0.003038087417500972,
            "median": 0.0027502883862044903,
            "std": 0.00171824565848989,
            "min": 0.0001319690055880846,
            "max": 0.019484678920166885,
            "sse": 0.026472231989372555,
        },
        "rpe_rot_deg": {
            "rmse": 0.28051922626732667,
            "mean": 0.22955611958091923,
            "median": 0.1878184571190636,
            "std": 0.16122972513953604,
            "min": 0.006038945919658329,
            "max": 1.2594035027080106,
            "sse": 170.99562189211144,
        },
    },
    # evo_ape tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt
    "fr2_desk_orb_none": {
        "args": ["fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", "--align", "none"],
        "pairs": 2174,
        "scale": 1.0,
        "ate": {
            "rmse": 3.17399354190223,
            "mean": 2.9496938875994747,
            "median": 2.594642464975095,
            "std": 1.1719816438389132,
            "min": 1.4603442833644174,
            "max": 5.066735062280106,
            "sse": 21901.386898776578,
        },
    },
    # evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt --align
    # evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt \
    #     --align --delta 1 --delta_unit f
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "fr1_rgbdslam_se3": {
        "args": ["freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", "--rpe-delta", "1"],
        "pairs": 785,
        "scale": 1.0,
        "ate": {
            "rmse": 0.013470088849733695,
            "mean": 0.012024498709110232,
            "median": 0.011183186775061079,
            "std": 0.006070809205890624,
            "min": 0.0009550461813178077,
            "max": 0.03475954589500904,
            "sse": 0.14243298549148023,
        },
        "rpe_trans": {
            "rmse": 0.005764370848928318,
            "mean": 0.004815609470203963,
            "median": 0.0041388577993644255,
            "std": 0.003168260834346895,
            "min": 0.00017106115346215636,
            "max": 0.020865814532330103,
            "sse": 0.02605072948663607,
        },
        "rpe_rot_deg": {
            "rmse": 0.3536131610447985,
            "mean": 0.3003065811400405,
            "median": 0.2621389996694454,
            "std": 0.1867035751882509,
            "min": 0.01693714352371137,
            "max": 1.6332960623334538,
            "sse": 98.03313784865017,
        },
    },
    # evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt --align
    # evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt \
    #     --align --delta 0.1 --delta_unit m
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "fr1_rgbdslam_se3_rpe_m": {
        "args": [
            "freiburg1_xyz-groundtruth.txt",
            "freiburg1_xyz-rgbdslam.txt",
            "--rpe-delta",
            "0.1",
            "--delta-unit",
            "m",
        ],
        "pairs": 785,
        "scale": 1.0,
        "ate": {
            "rmse": 0.013470088849733695,
            "mean": 0.012024498709110232,
            "median": 0.011183186775061079,
            "std": 0.006070809205890624,
            "min": 0.0009550461813178077,
            "max": 0.03475954589500904,
            "sse": 0.14243298549148023,
        },
        "rpe_trans": {
            "rmse": 0.014305008942373845,
            "mean": 0.012548034394815472,
            "median": 0.011559416124138423,
            "std": 0.006868778178680949,
            "min": 0.0015413055812110357,
            "max": 0.03865418101949766,
            "sse": 0.016370662467311652,
        },
        "rpe_rot_deg": {
            "rmse": 0.6842690463060345,
            "mean": 0.6028691455742885,
            "median": 0.5214110405656498,
            "std": 0.3236864548403243,
            "min": 0.03946140494926037,
            "max": 1.381712541078379,
            "sse": 37.4579302186056,
        },
    },
    # evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt
    "fr1_rgbdslam_none": {
        "args": ["freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", "--align", "none"],
        "pairs": 785,
        "scale": 1.0,
        "ate": {
            "rmse": 0.020079418378506592,
            "mean": 0.01806251843069654,
            "median": 0.016517756173282168,
            "std": 0.008770887660884508,
            "min": 0.0012561023047507462,
            "max": 0.04328943388403233,
            "sse": 0.31649868829899996,
        },
    },
    # evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt \
    #     --align --correct_scale
    # evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt \
    #     --align --correct_scale --delta 1 --delta_unit f
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "fr1_orb_mono_sim3": {
        "args": [
            "freiburg1_xyz-groundtruth.txt",
            "freiburg1_xyz-ORB_kf_mono.txt",
            "--align",
            "sim3",
            "--rpe-delta",
            "1",
        ],
        "pairs": 32,
        "scale": 1.1056223637370342,
        "ate": {
            "rmse": 0.00975458189868511,
            "mean": 0.008218698588816617,
            "median": 0.007909070259951356,
            "std": 0.005254032881924038,
            "min": 0.001876848097027465,
            "max": 0.027924001734076016,
            "sse": 0.0030448597765809675,
        },
        "rpe_trans": {
            "rmse": 0.013834917845974076,
            "mean": 0.01205827516547714,
            "median": 0.01114185876756802,
            "std": 0.0067825475920548625,
            "min": 0.0017835316098131222,
            "max": 0.030228647349587433,
            "sse": 0.00593355350595041,
        },
        "rpe_rot_deg": {
            "rmse": 0.8848489597243393,
            "mean": 0.7877250571083381,
            "median": 0.6521635615683905,
            "std": 0.4030470393501372,
            "min": 0.18531357955894356,
            "max": 1.7399584217516801,
            "sse": 24.27168812728261,
        },
    },
    # evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt --correct_scale
    "fr1_orb_mono_scale": {
        "args": [
            "freiburg1_xyz-groundtruth.txt",
            "freiburg1_xyz-ORB_kf_mono.txt",
            "--align",
            "scale",
        ],
        "pairs": 32,
        "scale": 1.1056223637370342,
        "ate": {
            "rmse": 2.016898721160651,
            "mean": 2.015184220304331,
            "median": 1.994050256436147,
            "std": 0.083144510678076,
            "min": 1.8828149046653768,
            "max": 2.189736767253241,
            "sse": 130.17217444542305,
        },
    },
    # evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt \
    #     --align --correct_scale
    # evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt \
    #     --align --correct_scale --delta 0.2 --delta_unit m
    "fr1_orb_mono_sim3_rpe_m": {
        "args": [
            "freiburg1_xyz-groundtruth.txt",
            "freiburg1_xyz-ORB_kf_mono.txt",
            "--align",
            "sim3",
            "--rpe-delta",
            "0.2",
            "--delta-unit",
            "m",
        ],
        "pairs": 32,
        "scale": 1.1056223637370342,
        "ate": {
            "rmse": 0.00975458189868511,
            "mean": 0.008218698588816617,
            "median": 0.007909070259951356,
            "std": 0.005254032881924038,
            "min": 0.001876848097027465,
            "max": 0.027924001734076016,
            "sse": 0.0030448597765809675,
        },
        "rpe_trans": {
            "rmse": 0.02242518509037644,
            "mean": 0.020047378645534793,
            "median": 0.019916613041666795,
            "std": 0.010049454501623317,
            "min": 0.006546837856725596,
            "max": 0.04293409478784827,
            "sse": 0.005531778189714059,
        },
    },
    # evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt --align
    # evo_rpe kitti KITTI_00_gt.txt KITTI_00_ORB.txt --align --delta 1 --delta_unit f
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "kitti00_orb_se3": {
        "args": ["KITTI_00_gt.txt", "KITTI_00_ORB.txt", "--format", "kitti", "--rpe-delta", "1"],
        "pairs": 4541,
        "scale": 1.0,
        "ate": {
            "rmse": 1.303449714565045,
            "mean": 1.1569971285389946,
            "median": 1.0656247695558074,
            "std": 0.6002822693968386,
            "min": 0.06931322021483205,
            "max": 3.587949120678975,
            "sse": 7715.073440293025,
        },
        "rpe_trans": {
            "rmse": 0.028120377017393467,
            "mean": 0.019301310981394062,
            "median": 0.014709043438546707,
            "std": 0.0204503055722859,
            "min": 0.0003124002631130694,
            "max": 0.3027124905953364,
            "sse": 3.5900304403455925,
        },
        "rpe_rot_deg": {
            "rmse": 0.11497352125979238,
            "mean": 0.05958345492311422,
            "median": 0.041074405275336325,
            "std": 0.09832966231153824,
            "min": 0.0022435537758794108,
            "max": 2.196615406942412,
            "sse": 60.013854082576714,
        },
    },
    # evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt --align
    # evo_rpe kitti KITTI_00_gt.txt KITTI_00_ORB.txt --align --delta 100 --delta_unit m
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "kitti00_orb_se3_rpe_m": {
        "args": ["KITTI_00_gt.txt", "KITTI_00_ORB.txt", "--rpe-delta", "100", "--delta-unit", "m"],
        "pairs": 4541,
        "scale": 1.0,
        "ate": {
            "rmse": 1.303449714565045,
            "mean": 1.1569971285389946,
            "median": 1.0656247695558074,
            "std": 0.6002822693968386,
            "min": 0.06931322021483205,
            "max": 3.587949120678975,
            "sse": 7715.073440293025,
        },
        "rpe_trans": {
            "rmse": 1.1939759245846715,
            "mean": 1.0544778257153993,
            "median": 0.9214941902755457,
            "std": 0.5600491260258743,
            "min": 0.27590912938470463,
            "max": 2.9596379599787306,
            "sse": 51.32082630556157,
        },
        "rpe_rot_deg": {
            "rmse": 0.7288356182425298,
            "mean": 0.6217988425718083,
            "median": 0.535254074277506,
            "std": 0.38022040686334846,
            "min": 0.13598675526292792,
            "max": 1.5762109745766912,
            "sse": 19.123248903082946,
        },
    },
    # evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt --align --correct_scale
    "kitti00_orb_sim3": {
        "args": ["KITTI_00_gt.txt", "KITTI_00_ORB.txt", "--align", "sim3"],
        "pairs": 4541,
        "scale": 1.0046980764526636,
        "ate": {
            "rmse": 0.937709073611404,
            "mean": 0.8726926319693136,
            "median": 0.8446910134863976,
            "std": 0.3430829008266512,
            "min": 0.17951466687995615,
            "max": 2.693499863613383,
            "sse": 3992.8936108752687,
        },
    },
    # evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt
    "kitti00_orb_none": {
        "args": ["KITTI_00_gt.txt", "KITTI_00_ORB.txt", "--align", "none"],
        "pairs": 4541,
        "scale": 1.0,
        "ate": {
            "rmse": 7.790288882656827,
            "mean": 7.01175040166684,
            "median": 6.801631674560281,
            "std": 3.3946954473076767,
            "min": 4.000000055511189e-09,
            "max": 13.458508807381891,
            "sse": 275586.9365744946,
        },
    },
    # evo_ape kitti KITTI_00_gt.txt KITTI_00_SPTAM.txt --align
    "kitti00_sptam_se3": {
        "args": ["KITTI_00_gt.txt", "KITTI_00_SPTAM.txt", "--format", "kitti"],
        "pairs": 4541,
        "scale": 1.0,
        "ate": {
            "rmse": 3.7384879075826025,
            "mean": 3.4909766330848586,
            "median": 3.642584641743261,
            "std": 1.3376748418045574,
            "min": 0.6947873474062781,
            "max": 7.7689774065712776,
            "sse": 63466.341223376854,
        },
    },
    # evo_ape kitti KITTI_00_gt.txt KITTI_00_SPTAM.txt --align --correct_scale
    "kitti00_sptam_sim3": {
        "args": ["KITTI_00_gt.txt", "KITTI_00_SPTAM.txt", "--align", "sim3"],
        "pairs": 4541,
        "scale": 1.0045265524039813,
        "ate": {
            "rmse": 3.635293564338599,
            "mean": 3.357305778620563,
            "median": 3.4798637552963627,
            "std": 1.394222797031597,
            "min": 0.22699281394826779,
            "max": 7.291831027981561,
            "sse": 60010.946576403134,
        },
    },
    # evo_ape euroc V102_groundtruth.csv V102.txt --align
    # evo_rpe euroc V102_groundtruth.csv V102.txt --align --delta 1 --delta_unit f
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "euroc_v102_se3": {
        "args": ["V102_groundtruth.csv", "V102.txt", "--format", "euroc", "--rpe-delta", "1"],
        "pairs": 798,
        "scale": 1.0,
        "ate": {
            "rmse": 0.09172711520685733,
            "mean": 0.08152162194619834,
            "median": 0.07791194901949527,
            "std": 0.042048648247395404,
            "min": 0.002619987097383053,
            "max": 0.25581673381397085,
            "sse": 6.714263204009318,
        },
        "rpe_trans": {
            "rmse": 0.015076710159641309,
            "mean": 0.006106922465380437,
            "median": 0.004183939336058221,
            "std": 0.013784508958960532,
            "min": 0.00011469502653256809,
            "max": 0.21740892442745743,
            "sse": 0.18116382982255166,
        },
        "rpe_rot_deg": {
            "rmse": 0.35761559488592853,
            "mean": 0.08987560074843895,
            "median": 0.033030032512071594,
            "std": 0.34613767505968457,
            "min": 0.0030677466329407386,
            "max": 4.939154960254687,
            "sse": 101.9274642233764,
        },
    },
    # evo_ape euroc V102_groundtruth.csv V102.txt --align --correct_scale
    "euroc_v102_sim3": {
        "args": ["V102_groundtruth.csv", "V102.txt", "--align", "sim3"],
        "pairs": 798,
        "scale": 0.9796982521745784,
        "ate": {
            "rmse": 0.08384138804295284,
            "mean": 0.0748410847826337,
            "median": 0.07194517866622532,
            "std": 0.03779140613324187,
            "min": 0.0070002905794235674,
            "max": 0.22665179238276975,
            "sse": 5.609443922477258,
        },
    },
    # evo_ape tum V101_gt.txt V101_openvins.txt --align
    # evo_rpe tum V101_gt.txt V101_openvins.txt --align --delta 1 --delta_unit f
    #   and the same with --pose_relation angle_deg (rpe_rot_deg)
    "v101_openvins_se3": {
        "args": ["V101_gt.txt", "V101_openvins.txt", "--rpe-delta", "1"],
        "pairs": 2760,
        "scale": 1.0,
        "ate": {
            "rmse": 0.05210196108597879,
            "mean": 0.0470827468354307,
            "median": 0.042657759055869784,
            "std": 0.02231208863902229,
            "min": 0.01403696253138526,
            "max": 0.12488621875724813,
            "sse": 7.492335603253379,
        },
        "rpe_trans": {
            "rmse": 0.0011375254423658778,
            "mean": 0.0007639741259728443,
            "median": 0.0006737468927981352,
            "std": 0.0008427975242451265,
            "min": 4.421668799061025e-05,
            "max": 0.03845051378817125,
            "sse": 0.003570047040269904,
        },
        "rpe_rot_deg": {
            "rmse": 0.01791205077127745,
            "mean": 0.010378113762072266,
            "median": 0.008938306045087897,
            "std": 0.014599188935495952,
            "min": 0.0006065208414170297,
            "max": 0.6950214860765637,
            "sse": 0.8852018718557535,
        },
    },
    # evo_ape tum V101_gt.txt V101_openvins.txt --align --correct_scale
    "v101_openvins_sim3": {
        "args": ["V101_gt.txt", "V101_openvins.txt", "--align", "sim3"],
        "pairs": 2760,
        "scale": 1.0040975443051978,
        "ate": {
            "rmse": 0.05155279012247762,
            "mean": 0.04526755406973681,
            "median": 0.04100553235001125,
            "std": 0.024668577542202974,
            "min": 0.012243418335320246,
            "max": 0.13120495647504946,
            "sse": 7.335224867577743,
        },
    },
}


def _run(args: list[str]) -> Any:
    return runner.invoke(app, args, catch_exceptions=False)


def _assert_stats(ours: dict[str, float], evo: dict[str, float], what: str) -> None:
    assert list(ours) == ["rmse", "mean", "median", "std", "min", "max", "sse"]
    for key, expected in evo.items():
        assert ours[key] == pytest.approx(expected, rel=REL, abs=1e-15), f"{what} {key}"


@pytest.mark.parametrize("case", sorted(EVO_REFERENCE))
def test_json_figures_equal_evo(trajectories_dir: Path, case: str) -> None:
    ref = EVO_REFERENCE[case]
    gt, est, *options = ref["args"]
    res = _run(
        ["eval", str(trajectories_dir / gt), str(trajectories_dir / est), *options, "--json"]
    )
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["pairs"] == ref["pairs"]
    assert data["scale"] == pytest.approx(ref["scale"], rel=REL)
    _assert_stats(data["ate"], ref["ate"], "ATE")
    if "rpe_trans" in ref:
        _assert_stats(data["rpe"]["trans"], ref["rpe_trans"], "RPE trans")
    if "rpe_rot_deg" in ref:
        _assert_stats(data["rpe"]["rot_deg"], ref["rpe_rot_deg"], "RPE rot")
    if "rpe_trans" not in ref:
        assert "rpe" not in data


def test_json_is_one_object_with_the_documented_keys(trajectories_dir: Path) -> None:
    d = trajectories_dir
    res = _run(
        [
            "eval",
            str(d / "V102_groundtruth.csv"),
            str(d / "V102.txt"),
            "-f",
            "euroc",
            "--json",
            "--rpe-delta",
            "1",
        ]
    )
    assert res.exit_code == 0
    data = json.loads(res.stdout)
    assert list(data) == ["alignment", "pairs", "ate", "rpe", "scale"]
    assert list(data["rpe"]) == ["trans", "rot_deg"]
    assert data["alignment"] == "se3"
    # V102.txt repeats four stamps; the warning goes to stderr, never into the JSON.
    assert "repeat" in res.stderr and "V102.txt" in res.stderr
    assert "warning" not in res.stdout


def test_table_output_shows_the_figures(trajectories_dir: Path) -> None:
    d = trajectories_dir
    res = _run(["eval", str(d / "fr2_desk_groundtruth.txt"), str(d / "fr2_desk_ORB.txt")])
    assert res.exit_code == 0
    # evo's documentation prints rmse 0.008119 for this pair with --align.
    assert "0.008119" in res.stdout
    assert "2174 of 2893" in res.stdout
    assert "RPE" not in res.stdout


def test_plot_writes_a_png_and_keeps_json_clean(trajectories_dir: Path, tmp_path: Path) -> None:
    d = trajectories_dir
    png = tmp_path / "ate.png"
    res = _run(
        [
            "eval",
            str(d / "freiburg1_xyz-groundtruth.txt"),
            str(d / "freiburg1_xyz-rgbdslam.txt"),
            "--plot",
            str(png),
            "--json",
        ]
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["pairs"] == 785
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 10_000
    assert [p.name for p in tmp_path.iterdir()] == ["ate.png"]


def test_kitti_times_files_pair_by_time(trajectories_dir: Path) -> None:
    d = trajectories_dir
    times = str(d / "KITTI_00_gt_times.txt")
    res = _run(
        [
            "eval",
            str(d / "KITTI_00_gt.txt"),
            str(d / "KITTI_00_ORB.txt"),
            "--gt-times",
            times,
            "--est-times",
            times,
            "--json",
        ]
    )
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["pairs"] == 4541
    assert data["ate"]["rmse"] == pytest.approx(
        EVO_REFERENCE["kitti00_orb_se3"]["ate"]["rmse"], rel=REL
    )


def _tum(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join(rows) + "\n")
    return path


def _line_trajectory(path: Path, n: int = 20, t0: float = 100.0) -> Path:
    return _tum(
        path, [f"{t0 + 0.1 * i:.6f} {0.1 * i} {0.02 * i * i} 0.0 0 0 0 1" for i in range(n)]
    )


def _assert_clean_error(res: Any, *needles: str) -> None:
    assert res.exit_code == 1
    assert "Traceback" not in res.output
    assert res.stdout == ""
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.stderr
    for needle in needles:
        assert needle in lines[0] or needle in res.stderr


def test_malformed_file_names_file_and_line(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    bad = _tum(
        tmp_path / "est.txt",
        ["# estimate", "1.0 0 0 0 0 0 0 1", "1.1 0 0 zero 0 0 0 1", "1.2 0 0 0 0 0 0 1"],
    )
    res = _run(["eval", str(gt), str(bad), "--format", "tum"])
    _assert_clean_error(res, "est.txt:3:", "zero")


def test_time_going_backwards_is_reported_at_its_line(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    bad = _tum(
        tmp_path / "est.txt", ["1.0 0 0 0 0 0 0 1", "1.2 0 0 0 0 0 0 1", "1.1 0 0 0 0 0 0 1"]
    )
    _assert_clean_error(_run(["eval", str(gt), str(bad)]), "est.txt:3:", "backwards")


def test_missing_file_is_exit_1(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    _assert_clean_error(
        _run(["eval", str(gt), str(tmp_path / "nope.txt"), "-f", "tum"]), "nope.txt"
    )


def test_too_few_matches_says_how_many_and_what_to_try(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt", t0=100.0)
    est = _line_trajectory(tmp_path / "est.txt", t0=101.9)
    res = _run(["eval", str(gt), str(est)])
    _assert_clean_error(
        res, "only 1 of 20 poses matched", "at least 3", "--t-max-diff", "--t-offset"
    )
    shifted = _run(["eval", str(gt), str(est), "--t-offset", "-1.9", "--json"])
    assert shifted.exit_code == 0, shifted.output
    data = json.loads(shifted.stdout)
    assert data["pairs"] == 20
    assert data["ate"]["max"] < 1e-9


def test_bad_option_values(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    est = _line_trajectory(tmp_path / "est.txt")
    _assert_clean_error(
        _run(["eval", str(gt), str(est), "--plot", str(tmp_path / "a.jpg")]), ".png"
    )
    _assert_clean_error(
        _run(["eval", str(gt), str(est), "--gt-times", str(gt)]), "--gt-times", "KITTI"
    )
    _assert_clean_error(_run(["eval", str(gt), str(est), "--rpe-delta", "1.5"]), "whole number")
    _assert_clean_error(
        _run(["eval", str(gt), str(est), "--rpe-delta", "50"]), "no pose pairs", "--rpe-delta"
    )
    assert _run(["eval", str(gt), str(est), "--align", "sim4"]).exit_code == 2


def test_identical_trajectories_score_zero(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    res = _run(["eval", str(gt), str(gt), "--rpe-delta", "2", "--json", "--align", "sim3"])
    data = json.loads(res.stdout)
    assert data["pairs"] == 20
    assert data["scale"] == pytest.approx(1.0, abs=1e-12)
    assert data["ate"]["rmse"] < 1e-9
    assert data["rpe"]["trans"]["max"] < 1e-9
    assert math.isclose(data["rpe"]["rot_deg"]["max"], 0.0, abs_tol=1e-6)


def test_help_teaches_with_examples() -> None:
    res = _run(["eval", "--help"])
    assert res.exit_code == 0
    for needle in ("--t-max-diff", "--rpe-delta", "sim3", "euroc", "slamcli eval"):
        assert needle in res.stdout


def test_command_module_imports_only_light_modules() -> None:
    code = (
        "import sys\n"
        "import slamcli.cli.evaluate\n"
        "heavy = ('matplotlib', 'slamcli.evaluation', 'slamcli.formats.trajectory', 'scipy')\n"
        "print(','.join(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


@pytest.mark.parametrize(
    ("name", "rows", "fmt", "needles"),
    [
        ("cols.txt", ["1.0 0 0 0 0 0 0 1", "1.1 0 0 0 0 0 1"], "tum", ["cols.txt:2:", "8"]),
        ("text.txt", ["1.0 0 0 0 0 0 0 1", "1.1 0 0 x 0 0 0 1"], "tum", ["text.txt:2:", "'x'"]),
        ("nan.txt", ["1.0 0 0 0 0 0 0 1", "1.1 0 nan 0 0 0 0 1"], "tum", ["nan.txt:2:", "finite"]),
        ("inf.txt", ["1.0 0 0 0 0 0 0 1", "1.1 0 0 0 inf 0 0 1"], "tum", ["inf.txt:2:", "finite"]),
        (
            "quat.txt",
            ["1.0 0 0 0 0 0 0 1", "1.1 0 0 0 0 0 0 2"],
            "tum",
            ["quat.txt:2:", "quaternion"],
        ),
        (
            "back.txt",
            ["1.0 0 0 0 0 0 0 1", "0.9 0 0 0 0 0 0 1"],
            "tum",
            ["back.txt:2:", "backwards"],
        ),
        ("empty.txt", ["# nothing here"], "tum", ["empty.txt"]),
        (
            "rot.kitti",
            ["1 0 0 0 0 1 0 0 0 0 1 0", "2 0 0 0 0 1 0 0 0 0 1 0"],
            "kitti",
            ["rot.kitti:2:", "rotation"],
        ),
        (
            "gt.csv",
            ["#timestamp,x,y,z,qw,qx,qy,qz", "1000000000,0,0,0,1,0,0,0", "2000000000,0,0,0,1,0"],
            "euroc",
            ["gt.csv:3:"],
        ),
    ],
)
def test_every_malformed_trajectory_is_one_line_exit_1(
    tmp_path: Path, name: str, rows: list[str], fmt: str, needles: list[str]
) -> None:
    bad = _tum(tmp_path / name, rows)
    res = _run(["eval", str(bad), str(bad), "--format", fmt])
    _assert_clean_error(res, *needles)


# Several estimates against one ground truth.

MULTI = [
    "freiburg1_xyz-rgbdslam.txt",
    "freiburg1_xyz-rgbdslam_drift.txt",
    "freiburg1_xyz-ORB_kf_mono.txt",
]


def _json(args: list[str]) -> Any:
    res = _run([*args, "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


@pytest.mark.parametrize(
    "options",
    [["--rpe-delta", "1"], ["--align", "sim3", "--rpe-delta", "0.1", "--delta-unit", "m"]],
)
def test_several_estimates_score_as_each_alone(trajectories_dir: Path, options: list[str]) -> None:
    gt = str(trajectories_dir / "freiburg1_xyz-groundtruth.txt")
    ests = [str(trajectories_dir / name) for name in MULTI]
    data = _json(["eval", gt, *ests, *options])
    assert list(data) == ["groundtruth", "alignment", "estimates"]
    assert data["groundtruth"] == gt
    assert data["alignment"] == ("sim3" if "sim3" in options else "se3")
    assert [e["path"] for e in data["estimates"]] == ests
    for entry, est in zip(data["estimates"], ests, strict=True):
        alone = _json(["eval", gt, est, *options])
        assert list(entry) == ["path", *alone]
        assert entry["pairs"] == alone["pairs"]
        assert entry["scale"] == pytest.approx(alone["scale"], rel=1e-12)
        assert entry["alignment"] == data["alignment"]
        _assert_stats(entry["ate"], alone["ate"], f"{est} ATE")
        _assert_stats(entry["rpe"]["trans"], alone["rpe"]["trans"], f"{est} RPE trans")
        _assert_stats(entry["rpe"]["rot_deg"], alone["rpe"]["rot_deg"], f"{est} RPE rot")
    # The estimates really differ, so a mix-up of rows would show.
    assert len({e["pairs"] for e in data["estimates"]}) == 2
    assert len({e["ate"]["rmse"] for e in data["estimates"]}) == 3


def test_several_estimates_match_evo(trajectories_dir: Path) -> None:
    d = trajectories_dir
    data = _json(
        [
            "eval",
            str(d / "freiburg1_xyz-groundtruth.txt"),
            str(d / "freiburg1_xyz-rgbdslam.txt"),
            str(d / "freiburg1_xyz-ORB_kf_mono.txt"),
            "--align",
            "sim3",
            "--rpe-delta",
            "1",
        ]
    )
    rgbd, mono = data["estimates"]
    ref = EVO_REFERENCE["fr1_orb_mono_sim3"]
    assert mono["pairs"] == ref["pairs"]
    assert mono["scale"] == pytest.approx(ref["scale"], rel=REL)
    _assert_stats(mono["ate"], ref["ate"], "ATE")
    _assert_stats(mono["rpe"]["trans"], ref["rpe_trans"], "RPE trans")
    assert rgbd["pairs"] == 785


def _table_rows(stdout: str) -> dict[str, list[str]]:
    """The rows of the estimates table: name -> its cells."""
    rows = {}
    for line in stdout.splitlines():
        cells = [c.strip() for c in line.split("│")]
        if len(cells) > 2:
            rows[cells[0]] = cells[1:]
    return rows


def test_table_has_a_row_per_estimate_and_marks_the_best(trajectories_dir: Path) -> None:
    d = trajectories_dir
    gt = str(d / "freiburg1_xyz-groundtruth.txt")
    ests = [str(d / "freiburg1_xyz-rgbdslam.txt"), str(d / "freiburg1_xyz-ORB_kf_mono.txt")]
    for align, best in (
        ("se3", "freiburg1_xyz-rgbdslam.txt"),
        ("sim3", "freiburg1_xyz-ORB_kf_mono.txt"),
    ):
        res = _run(["eval", gt, *ests, "--align", align, "--rpe-delta", "1"])
        assert res.exit_code == 0, res.output
        rows = _table_rows(res.stdout)
        assert sorted(rows) == ["freiburg1_xyz-ORB_kf_mono.txt", "freiburg1_xyz-rgbdslam.txt"]
        data = _json(["eval", gt, *ests, "--align", align, "--rpe-delta", "1"])
        for name, entry in zip(
            ["freiburg1_xyz-rgbdslam.txt", "freiburg1_xyz-ORB_kf_mono.txt"],
            data["estimates"],
            strict=True,
        ):
            cells = rows[name]
            assert cells[0].split()[0] == str(entry["pairs"])
            assert cells[1].rstrip("*") == f"{entry['ate']['rmse']:.6f}"
            assert cells[1].endswith("*") == (name == best)
            assert cells[2:5] == [f"{entry['ate'][k]:.6f}" for k in ("mean", "median", "max")]
            assert cells[5] == f"{entry['rpe']['trans']['rmse']:.6f}"
            assert cells[6] == f"{entry['rpe']['rot_deg']['rmse']:.6f}"
    without_rpe = _run(["eval", gt, *ests])
    assert "RPE" not in without_rpe.stdout
    assert len(_table_rows(without_rpe.stdout)["freiburg1_xyz-rgbdslam.txt"]) == 5


def test_rows_sharing_a_file_name_show_enough_of_the_path(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    for sub in ("x/a", "y/a", "z"):
        (tmp_path / sub).mkdir(parents=True)
    a = _line_trajectory(tmp_path / "x" / "a" / "est.txt")
    b = _line_trajectory(tmp_path / "y" / "a" / "est.txt")
    c = _line_trajectory(tmp_path / "z" / "other.txt")
    res = _run(["eval", str(gt), str(a), str(b), str(c)])
    assert res.exit_code == 0, res.output
    assert sorted(_table_rows(res.stdout)) == ["other.txt", "x/a/est.txt", "y/a/est.txt"]


def _run_folder(path: Path, trajectory: Path | None) -> Path:
    path.mkdir(parents=True)
    (path / "run.json").write_text(json.dumps({"pipeline": "dense", "outputs": []}))
    if trajectory is not None:
        (path / "trajectory.tum").write_bytes(trajectory.read_bytes())
    return path


def test_a_run_folder_is_an_estimate(trajectories_dir: Path, tmp_path: Path) -> None:
    d = trajectories_dir
    gt = str(d / "freiburg1_xyz-groundtruth.txt")
    rgbd = d / "freiburg1_xyz-rgbdslam.txt"
    run = _run_folder(tmp_path / "runs" / "dense", rgbd)
    mono = str(d / "freiburg1_xyz-ORB_kf_mono.txt")
    data = _json(["eval", gt, str(run), mono])
    assert [e["path"] for e in data["estimates"]] == [str(run), mono]
    alone = _json(["eval", gt, str(rgbd)])
    assert data["estimates"][0]["pairs"] == alone["pairs"] == 785
    _assert_stats(data["estimates"][0]["ate"], alone["ate"], "ATE")
    res = _run(["eval", gt, str(run), mono])
    assert sorted(_table_rows(res.stdout)) == ["dense", "freiburg1_xyz-ORB_kf_mono.txt"]
    # One run folder alone scores its trajectory.tum too.
    single = _json(["eval", gt, str(run)])
    assert single == alone


def test_run_folder_without_trajectory_is_named(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    est = _line_trajectory(tmp_path / "est.txt")
    empty = _run_folder(tmp_path / "ekf_run", None)
    _assert_clean_error(_run(["eval", str(gt), str(est), str(empty)]), "ekf_run", "trajectory.tum")
    plain = tmp_path / "plain"
    plain.mkdir()
    _assert_clean_error(_run(["eval", str(gt), str(est), str(plain)]), "plain", "run.json")


@pytest.mark.parametrize("json_out", [[], ["--json"]])
def test_a_bad_estimate_among_several_stops_before_any_table(
    tmp_path: Path, json_out: list[str]
) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt")
    good = _line_trajectory(tmp_path / "good.txt")
    bad = _tum(tmp_path / "bad.txt", ["100.0 0 0 0 0 0 0 1", "100.1 0 0 zero 0 0 0 1"])
    for order in ([good, bad], [bad, good]):
        res = _run(["eval", str(gt), *map(str, order), *json_out])
        _assert_clean_error(res, "bad.txt:2:", "zero")
    missing = tmp_path / "missing.txt"
    _assert_clean_error(_run(["eval", str(gt), str(good), str(missing), *json_out]), "missing.txt")


def test_an_estimate_matching_too_few_poses_is_named(tmp_path: Path) -> None:
    gt = _line_trajectory(tmp_path / "gt.txt", t0=100.0)
    good = _line_trajectory(tmp_path / "good.txt", t0=100.0)
    late = _line_trajectory(tmp_path / "late.txt", t0=101.9)
    png = tmp_path / "m.png"
    res = _run(["eval", str(gt), str(good), str(late), "--plot", str(png)])
    _assert_clean_error(res, "late.txt: only 1 of 20 poses matched", "--t-offset")
    assert "good.txt" not in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.txt", "gt.txt", "late.txt"]


def test_plot_of_several_estimates_is_one_png(trajectories_dir: Path, tmp_path: Path) -> None:
    d = trajectories_dir
    gt = str(d / "freiburg1_xyz-groundtruth.txt")
    ests = [str(d / "freiburg1_xyz-rgbdslam.txt"), str(d / "freiburg1_xyz-ORB_kf_mono.txt")]
    png = tmp_path / "many.png"
    res = _run(["eval", gt, *ests, "--align", "sim3", "--plot", str(png), "--json"])
    assert res.exit_code == 0, res.output
    assert len(json.loads(res.stdout)["estimates"]) == 2
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 10_000
    assert [p.name for p in tmp_path.iterdir()] == ["many.png"]
    from PIL import Image

    with Image.open(png) as im:
        assert im.size == (1200, 500)
        colours = {c for _, c in im.convert("RGB").getcolors(1_000_000) or []}
    # The first two colours of the cycle (tab:blue, tab:orange) are both drawn.
    assert (31, 119, 180) in colours and (255, 127, 14) in colours
    shown = _run(["eval", gt, *ests, "--plot", str(png)])
    assert shown.exit_code == 0
    assert "Written" in shown.stdout and str(png) in shown.stdout.replace("\n", "")
