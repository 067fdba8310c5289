"""The IMU in the visual pipeline: samples, initialisation, per-keyframe inertial state and the
IMU's prediction of a frame's pose (ORB-SLAM3's visual-inertial mode).

- **Samples** arrive as :class:`~slamcli.types.ImuFrame` between the images, in stamp order;
  they are checked as they come (stamps that do not increase, readings that are not finite)
  and kept in growing arrays.
- **Initialisation.** Once the current map's keyframes span ``imu_init_s`` seconds, each new
  keyframe tries :func:`slamcli.inertial.initialise_inertial` on the map's keyframes until
  one succeeds (a window whose motion leaves scale or gravity undetermined is refused). The
  map is then turned and scaled into the metric, gravity-aligned world (z up), and every
  keyframe gets a velocity and a bias. ``imu_refine_s`` seconds later the whole map is
  adjusted again with its inertial terms (ORB-SLAM3 refines at 5 and 15 s).
- **Keyframe states.** A new keyframe's velocity and bias are predicted from the keyframe
  before it; the local bundle adjustment (:mod:`slamcli.inertial.bundle`) then estimates them.
- **Prediction.** A frame's pose is predicted from the latest keyframe's state and the IMU
  since then, which the tracker uses in place of the constant-velocity model, and which poses
  a frame when vision fails (``imu_max_blind_s`` at most).
"""

from __future__ import annotations

import logging
import math
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.geometry import inverse
from slamcli.inertial.clock import ClockOffset, estimate_clock_offset
from slamcli.inertial.observability import ScaleInformation, scale_information
from slamcli.inertial.preintegration import ImuNoise, bias_of, integrate, interval_readings
from slamcli.pipelines.visual.atlas import Keyframe
from slamcli.pipelines.visual.parts import Part, Shared

if TYPE_CHECKING:
    import gtsam

    from slamcli.inertial.bundle import InertialTerms
    from slamcli.inertial.initialisation import InertialInit
    from slamcli.types import ImuFrame

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

logger = logging.getLogger(__name__)

GYRO_AGREEMENT_DEG = 1.0
"""The largest difference between a two-view rotation and the gyroscope's over the same
interval that a monocular initialisation accepts, on top of what an unknown bias of
:data:`GYRO_BIAS_BOUND` turns in that time (the gyroscope's noise over a second is a small
fraction of a degree)."""
MONO_MAX_CHI2_PER_DOF = 100.0
"""The largest misfit per degree of freedom (``2 · cost / dof``) between a monocular map and
the IMU that its initialisation accepts: residuals ten times the map's stated noise (3 mm)
on average. Before the IMU holds it, a map made by one camera drifts in scale over seconds
(by tens of per cent on EuRoC's fast flights), which a map with depth does not (25 there);
the bundle adjustment with inertial terms that follows corrects that drift, while a window
that fits far worse still (a wrong calibration, clock offset, or a broken map) is
refused."""
WINDOW_SPANS = 5
"""An initialisation window spans at most this many times ``imu_init_s``: gentle motion needs
seconds more than ``imu_init_s`` to determine the scale, and a longer window costs little."""
SCALE_DOUBT_STD = 0.02
"""A monocular run whose motion determines its metric scale to worse than this (relative
standard deviation, at best: :mod:`slamcli.inertial.observability`) says so in its doubts.
The bound takes vision as perfect and the scale as one over the run; a real map also drifts
in scale between keyframes, so the error can be several times the bound: `synth stereo`'s
18 s loop at 10 Hz (a steady turn, whose centripetal acceleration the body carries round
like a bias) bounds it at 4.4 % and ends 19 % small."""
GYRO_BIAS_BOUND = 0.1
"""rad/s: the largest gyroscope bias assumed before it is estimated (EuRoC's MEMS IMU starts
MH_05 at 0.077 rad/s about z)."""


class Inertial(Part):
    """The IMU of one visual run (see the module docstring).

    Attributes:
        noise: the IMU's noise model (None: the run is visual only).
        states: keyframe id -> (9,) velocity (m/s, world), gyroscope bias (rad/s) and
            accelerometer bias (m/s²), for the keyframes of initialised maps.
        inits: map id -> its initialisation.
        records: one dict per initialisation and refinement, for ``run.json``.
    """

    def __init__(self, shared: Shared) -> None:
        super().__init__(shared)
        self.noise: ImuNoise | None = None
        self._t = np.zeros(1024, np.int64)
        self._g = np.zeros((1024, 3))
        self._a = np.zeros((1024, 3))
        self._n = 0
        self.states: dict[int, F64] = {}
        self.inits: dict[int, InertialInit] = {}
        self.records: list[dict[str, Any]] = []
        self._refined: set[int] = set()
        self._first_image_ns: int | None = None
        self.attempts = 0
        self.dropped = 0
        self.last_refusal = ""
        self.data_loss: list[str] = []
        self.clock: ClockOffset | None = None
        """The IMU clock's offset from the camera's, estimated when an initialisation is
        refused (:mod:`slamcli.inertial.clock`)."""
        self._frame_s = 0.05

    # -- samples ------------------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        """Whether the run is visual-inertial."""
        return self.noise is not None

    @property
    def last_stamp_ns(self) -> int | None:
        """The stamp of the last sample, None before the first."""
        return int(self._t[self._n - 1]) if self._n else None

    def add(self, frame: ImuFrame) -> None:
        """Keep one IMU sample; one whose stamp does not follow the last kept one is dropped
        and counted (``dropped``).

        Raises:
            InputError: a reading that is missing or not finite.
        """
        if frame.gyro_radps is None or frame.accel_mps2 is None:
            raise InputError(
                f"IMU sample at {frame.stamp_ns} ns: it lacks a gyroscope or accelerometer "
                "reading; visual-inertial SLAM needs both",
                hint="run without the IMU (--set imu=false)",
            )
        g = np.asarray(frame.gyro_radps, np.float64).reshape(3)
        a = np.asarray(frame.accel_mps2, np.float64).reshape(3)
        if not (np.isfinite(g).all() and np.isfinite(a).all()):
            raise InputError(
                f"IMU sample at {frame.stamp_ns} ns: a reading is not finite",
                hint="check the IMU log ('slamcli info'), or run without it (--set imu=false)",
            )
        if self._n and frame.stamp_ns <= self._t[self._n - 1]:
            # A duplicate or backwards stamp: the sample cannot be placed in time.
            self.dropped += 1
            return
        if self._n == self._t.size:
            self._t = np.concatenate([self._t, np.zeros_like(self._t)])
            self._g = np.concatenate([self._g, np.zeros_like(self._g)])
            self._a = np.concatenate([self._a, np.zeros_like(self._a)])
        self._t[self._n], self._g[self._n], self._a[self._n] = frame.stamp_ns, g, a
        self._n += 1

    def check(self, report: dict[str, Any] | None, frame_s: float | None) -> None:
        """Act on the source's IMU checks (:func:`slamcli.formats.imu_checks.check_imu`'s
        report, as ``info`` gives it) before the run: units that are not rad/s and m/s² and
        an IMU that misses most images refuse the run; gaps, repeated or backwards stamps and
        saturated samples let it go on, as lost data (``data_loss``: the run ends with exit
        code 3).

        Raises:
            InputError: the gyroscope looks like deg/s, the accelerometer is not in m/s², or
                the IMU's clock is off the camera's (most images outside its span).
        """
        if frame_s:
            self._frame_s = float(frame_s)
        if not report:
            return
        where = report.get("where", "the IMU")
        fatal = []
        if report.get("gyro_units_suspect"):
            fatal.append(
                f"{where}: the gyroscope looks like deg/s, not rad/s: "
                f"{report.get('gyro_units_reason')}"
            )
        if report.get("accel_units_suspect"):
            fatal.append(
                f"{where}: the accelerometer is not in m/s^2: {report.get('accel_units_reason')}"
            )
        offset = report.get("camera_offset_s")
        images = int(report.get("images") or 0)
        uncovered = int(report.get("uncovered_images") or 0)
        if images and uncovered > images // 2:
            shift = f" (shifting its stamps by {offset:.3f} s would cover them)" if offset else ""
            fatal.append(
                f"{where}: {uncovered} of {images} images have no IMU sample around them: the "
                f"IMU's clock is off the camera's{shift}"
            )
        elif offset and frame_s and abs(offset) > frame_s:
            fatal.append(
                f"{where}: its stamps are offset from the camera's by {offset:.3f} s, more than "
                f"a frame ({frame_s:.3f} s)"
            )
        if fatal:
            raise InputError(
                "; ".join(fatal),
                hint="fix the IMU's units or stamps, or run without the IMU: --set imu=false",
            )
        lost = []
        if report.get("gaps"):
            lost.append(
                f"{where}: {report['gaps']} gap(s) without samples, the longest "
                f"{report.get('largest_gap_s', 0.0):.3f} s"
            )
        for key, what in (("duplicates", "repeat an earlier stamp"), ("backwards", "go back")):
            if report.get(key):
                lost.append(f"{where}: {report[key]} sample(s) {what}")
        stuck = sum(int(n) for n in (report.get("saturated") or {}).values())
        if stuck:
            lost.append(f"{where}: {stuck} sample(s) stuck at their axis' extreme (saturated)")
        self.data_loss = lost

    def _clock_offset(self, map_id: int) -> ClockOffset | None:
        """The IMU clock's offset estimated on the keyframes of map ``map_id`` (kept in
        :attr:`clock`)."""
        kfs = self.map.live(map_id)
        if len(kfs) < 3:
            return None
        r_bc = self.rig.body_from_camera[:3, :3]
        world_from_body = np.stack([k.cam_from_world[:3, :3].T @ r_bc.T for k in kfs])
        t, gyro, _ = self.samples()
        stamps = np.array([k.stamp_ns for k in kfs], dtype=np.int64)
        self.clock = estimate_clock_offset(stamps, world_from_body, t, gyro)
        return self.clock

    def samples(self) -> tuple[I64, F64, F64]:
        """The samples so far: stamps (ns), gyro (rad/s), accel (m/s²)."""
        n = self._n
        return self._t[:n], self._g[:n], self._a[:n]

    def covers(self, t0_ns: int, t1_ns: int) -> bool:
        """Whether samples lie at or before ``t0`` and at or after ``t1``."""
        return self._n > 0 and self._t[0] <= t0_ns and self._t[self._n - 1] >= t1_ns

    def _preintegrate(
        self, t0_ns: int, t1_ns: int, bias: F64
    ) -> gtsam.PreintegratedImuMeasurements:
        """The IMU's motion over [t0, t1] preintegrated around ``bias`` (gyroscope, then
        accelerometer)."""
        import gtsam

        assert self.noise is not None
        pim = gtsam.PreintegratedImuMeasurements(self.noise.params(), bias_of(bias))
        return integrate(pim, self.readings(t0_ns, t1_ns))

    def readings(self, t0_ns: int, t1_ns: int) -> tuple[F64, F64, F64]:
        """The piecewise-constant readings over [t0, t1] (see
        :func:`~slamcli.inertial.preintegration.interval_readings`)."""
        return interval_readings(*self.samples(), int(t0_ns), int(t1_ns))

    # -- state -------------------------------------------------------------------------------

    def active(self, map_id: int) -> bool:
        """Whether map ``map_id`` is initialised (metric and gravity-aligned)."""
        return map_id in self.inits

    def chain(self, map_id: int) -> list[Keyframe]:
        """The live keyframes of map ``map_id`` with an inertial state, oldest first."""
        return [k for k in self.map.live(map_id) if k.id in self.states]

    def scale_determination(self, map_id: int) -> ScaleInformation | None:
        """How well the motion of map ``map_id`` fixes its metric scale: for a monocular map
        with an inertial state on three keyframes or more, else None."""
        chain = self.chain(map_id) if self.rig.mono and self.active(map_id) else []
        if len(chain) < 3 or self.noise is None:
            return None
        first = self.states[chain[0].id]
        return scale_information(
            [k.stamp_ns for k in chain],
            np.stack([self.world_from_body(k) for k in chain]),
            self.samples(),
            self.noise,
            gyro_bias=first[3:6],
            accel_bias=first[6:9],
        )

    def world_from_body(self, kf: Keyframe) -> F64:
        """(4, 4) the body's pose at keyframe ``kf``."""
        return inverse(kf.cam_from_world) @ inverse(self.rig.body_from_camera)

    def predict_state(self, kf: Keyframe, stamp_ns: int) -> tuple[F64, F64] | None:
        """``world_from_body`` (4, 4) and velocity (3,) at ``stamp_ns``, integrated from
        ``kf``'s state; None without IMU samples covering the interval."""
        import gtsam

        state = self.states[kf.id]
        if stamp_ns == kf.stamp_ns:
            return self.world_from_body(kf), state[:3].copy()
        if stamp_ns < kf.stamp_ns or not self.covers(kf.stamp_ns, stamp_ns):
            return None
        pim = self._preintegrate(kf.stamp_ns, stamp_ns, state[3:9])
        start = gtsam.NavState(gtsam.Pose3(self.world_from_body(kf)), state[:3])
        nav = pim.predict(start, bias_of(state[3:9]))
        return nav.pose().matrix(), np.asarray(nav.velocity(), np.float64)

    def predict_back(self, kf: Keyframe, stamp_ns: int) -> tuple[F64, F64] | None:
        """``world_from_body`` and velocity at ``stamp_ns`` before keyframe ``kf``,
        integrated back from its state: with ``ΔR, Δv, Δp`` preintegrated over
        [``stamp_ns``, kf] in the earlier body frame, ``R = R_kf ΔRᵀ``,
        ``v = v_kf - g Δt - R Δv`` and ``p = p_kf - v Δt - ½ g Δt² - R Δp``."""
        assert self.noise is not None
        if stamp_ns > kf.stamp_ns or not self.covers(stamp_ns, kf.stamp_ns):
            return None
        state = self.states[kf.id]
        end = self.world_from_body(kf)
        if stamp_ns == kf.stamp_ns:
            return end, state[:3].copy()
        pim = self._preintegrate(stamp_ns, kf.stamp_ns, state[3:9])
        g = np.array([0.0, 0.0, -self.noise.gravity_mps2])
        t = pim.deltaTij()
        r = end[:3, :3] @ pim.deltaRij().matrix().T
        v = state[:3] - g * t - r @ pim.deltaVij()
        body = np.eye(4)
        body[:3, :3] = r
        body[:3, 3] = end[:3, 3] - v * t - 0.5 * g * t * t - r @ pim.deltaPij()
        return body, v

    def bridge(self, map_id: int, stamp_ns: int) -> F64 | None:
        """``cam_from_world`` at ``stamp_ns`` between two keyframes of map ``map_id``, from
        the IMU alone (a frame vision could not pose): integrated forward from the keyframe
        before and back from the one after, the positions blended linearly in time so that
        the bias error left in either integration does not pile up at the far end. None
        without a keyframe on both sides."""
        chain = self.chain(map_id)
        before = [k for k in chain if k.stamp_ns <= stamp_ns]
        after = [k for k in chain if k.stamp_ns >= stamp_ns]
        if not before or not after:
            return None
        a, b = before[-1], after[0]
        fwd = self.predict_state(a, stamp_ns)
        back = self.predict_back(b, stamp_ns)
        if fwd is None or back is None:
            return None
        w = 0.0 if b.stamp_ns == a.stamp_ns else (stamp_ns - a.stamp_ns) / (b.stamp_ns - a.stamp_ns)
        body = fwd[0].copy()
        body[:3, 3] = (1.0 - w) * fwd[0][:3, 3] + w * back[0][:3, 3]
        return inverse(body @ self.rig.body_from_camera)

    def keep_gravity(self, kfs: list[Keyframe], before: F64, after: F64) -> F64:
        """A loop's correction of an initialised map (``world_from_camera`` of ``kfs``,
        ``before`` and ``after`` the essential graph's optimisation, (K, 4, 4)) with each
        keyframe's rotation change kept to its part about gravity (yaw): the IMU observes
        the map's tilt, so a loop may turn it about z and move it, 4 degrees of freedom, as
        ORB-SLAM3's inertial loop closing. The keyframes' velocities turn with them."""
        out = np.asarray(after, np.float64).copy()
        for i, k in enumerate(kfs):
            delta = out[i, :3, :3] @ before[i, :3, :3].T
            yaw = math.atan2(delta[1, 0] - delta[0, 1], delta[0, 0] + delta[1, 1])
            rz = np.array(
                [
                    [math.cos(yaw), -math.sin(yaw), 0.0],
                    [math.sin(yaw), math.cos(yaw), 0.0],
                    [0, 0, 1],
                ]
            )
            out[i, :3, :3] = rz @ before[i, :3, :3]
            if k.id in self.states:
                self.states[k.id][:3] = rz @ self.states[k.id][:3]
        return out

    def predict(self, stamp_ns: int) -> F64 | None:
        """``cam_from_world`` of a frame at ``stamp_ns`` in the current map, predicted from
        its latest keyframe's state; None when the map is not initialised or the IMU does not
        cover the interval."""
        if not self.enabled or not self.active(self.atlas.current):
            return None
        chain = self.chain(self.atlas.current)
        if not chain:
            return None
        got = self.predict_state(chain[-1], stamp_ns)
        if got is None:
            return None
        return inverse(got[0] @ self.rig.body_from_camera)

    def new_keyframe(self, kf: Keyframe) -> None:
        """Give a keyframe of an initialised map the state predicted from the one before it
        (velocity carried by the IMU, biases kept)."""
        if not self.enabled or not self.active(kf.map_id) or kf.id in self.states:
            return
        chain = self.chain(kf.map_id)
        if not chain:
            return
        prev = chain[-1]
        got = self.predict_state(prev, kf.stamp_ns)
        state = self.states[prev.id].copy()
        if got is not None:
            state[:3] = got[1]
        self.states[kf.id] = state

    def terms(self, chain: list[Keyframe], held: int, anchored: bool = False) -> InertialTerms:
        """The inertial part of a bundle adjustment whose first ``len(chain)`` keyframes are
        ``chain`` (oldest first), the first ``held`` held (or, ``anchored``, the first
        anchored: see :class:`~slamcli.inertial.bundle.InertialTerms`)."""
        from slamcli.inertial.bundle import InertialTerms

        assert self.noise is not None
        states = np.stack([self.states[k.id] for k in chain])
        return InertialTerms(
            chain=np.arange(len(chain), dtype=np.int64),
            velocities=states[:, :3].copy(),
            biases=states[:, 3:].copy(),
            intervals=[self.readings(a.stamp_ns, b.stamp_ns) for a, b in pairwise(chain)],
            held=held,
            noise=self.noise,
            body_from_camera=self.rig.body_from_camera.copy(),
            anchored=anchored,
        )

    def take(self, kf_ids: list[int], velocities: F64, biases: F64) -> None:
        """The states a bundle adjustment estimated, for the keyframes that still exist."""
        for i, k in enumerate(kf_ids):
            if k in self.states and not self.map.keyframes[k].culled:
                self.states[k] = np.concatenate([velocities[i], biases[i]])

    # -- initialisation ----------------------------------------------------------------------

    def note_image(self, stamp_ns: int) -> None:
        """The first image's stamp (the initialisation's time is counted from it)."""
        if self._first_image_ns is None:
            self._first_image_ns = stamp_ns

    def try_initialise(self, map_id: int) -> InertialInit | None:
        """Initialise map ``map_id`` when its keyframes span ``imu_init_s`` and the IMU
        determines its scale and gravity; returns the initialisation, None when not (yet)."""
        from slamcli.inertial.initialisation import MAX_CHI2_PER_DOF, initialise_inertial

        if not self.enabled or self.active(map_id):
            return None
        kfs = self.window(map_id)
        if not kfs:
            return None
        if not self.covers(kfs[0].stamp_ns, kfs[-1].stamp_ns):
            return None
        assert self.noise is not None
        self.attempts += 1
        refusals: list[str] = []
        init = initialise_inertial(
            [(k.stamp_ns, inverse(k.cam_from_world)) for k in kfs],
            self.samples(),
            self.noise,
            self.rig.body_from_camera,
            prior_scale=None if self.rig.mono else 1.0,
            max_chi2_per_dof=MONO_MAX_CHI2_PER_DOF if self.rig.mono else MAX_CHI2_PER_DOF,
            refusals=refusals,
        )
        self.stats.counts["imu_init_attempts"] += 1
        if init is None:
            self.last_refusal = refusals[-1] if refusals else ""
            clock = self._clock_offset(map_id)
            if clock is not None and clock.significant(self._frame_s):
                late = "late" if clock.shift_s > 0 else "early"
                self.last_refusal = (
                    f"the IMU's clock looks {abs(clock.shift_s) * 1e3:.0f} ms {late} against the "
                    f"camera's (the gyroscope's turns fit the map's {clock.gain:.1f} times "
                    "better shifted so): give the camera-IMU time offset as Kalibr's "
                    f"timeshift_cam_imu: {clock.shift_s:.3f} in a camchain with --calib"
                )
            return None
        self.inits[map_id] = init
        for k, v in zip(kfs, init.velocities, strict=True):
            self.states[k.id] = np.concatenate([v, init.gyro_bias, init.accel_bias])
        first = self._first_image_ns if self._first_image_ns is not None else kfs[0].stamp_ns
        self.records.append(
            {
                "map": map_id,
                "kind": "initialisation",
                "after_s": round((kfs[-1].stamp_ns - first) * 1e-9, 3),
                "keyframes": len(kfs),
                "scale": round(init.scale, 6),
                "scale_std": round(init.scale_std, 6),
                "gravity_in_map": [round(float(x), 6) for x in init.gravity_visual],
                "gravity_std_deg": round(init.gravity_std_deg, 4),
                "gyro_bias": [round(float(x), 7) for x in init.gyro_bias],
                "accel_bias": [round(float(x), 6) for x in init.accel_bias],
                "chi2_per_dof": round(init.chi2_per_dof, 4),
            }
        )
        logger.info(
            "IMU initialised on map %d after %.2f s: scale %.4f, gravity sigma %.2f deg",
            map_id,
            self.records[-1]["after_s"],
            init.scale,
            init.gravity_std_deg,
        )
        return init

    def agrees(self, t0_ns: int, t1_ns: int, cam1_from_cam0: F64) -> bool:
        """Whether a camera rotation between ``t0`` and ``t1`` (``cam1_from_cam0``, 3 × 3)
        agrees with the gyroscope's, integrated without bias, within
        :data:`GYRO_AGREEMENT_DEG` and what :data:`GYRO_BIAS_BOUND` turns over the interval
        (True when the IMU does not cover the interval)."""
        if not self.enabled or t1_ns <= t0_ns or not self.covers(t0_ns, t1_ns):
            return True
        body0_from_body1 = self._preintegrate(t0_ns, t1_ns, np.zeros(6)).deltaRij().matrix()
        r_bc = self.rig.body_from_camera[:3, :3]
        cam0_from_cam1 = r_bc.T @ body0_from_body1 @ r_bc
        off = cam1_from_cam0 @ cam0_from_cam1
        angle = np.degrees(np.arccos(np.clip((np.trace(off) - 1.0) / 2.0, -1.0, 1.0)))
        allowed = GYRO_AGREEMENT_DEG + np.degrees(GYRO_BIAS_BOUND) * (t1_ns - t0_ns) * 1e-9
        return bool(angle <= allowed)

    def window(self, map_id: int) -> list[Keyframe]:
        """The keyframes an initialisation of map ``map_id`` is tried on: the latest ones
        whose rotations, keyframe to keyframe, agree with the gyroscope (:meth:`agrees`),
        spanning at most :data:`WINDOW_SPANS` times ``imu_init_s``; empty while they span less than
        ``imu_init_s``. A monocular map started close to a surface can go wrong in its first
        keyframes (a scale that collapses as the far scene comes into view, rotations
        traded for translations): it is initialised on the keyframes after them, and
        :meth:`place_head` places the first ones on the IMU."""
        kfs = self.map.live(map_id)
        newest = kfs[-1].stamp_ns if kfs else 0
        span_ns = round(WINDOW_SPANS * self.config.imu_init_s * 1e9)
        start = len(kfs) - 1
        while start > 0 and newest - kfs[start - 1].stamp_ns <= span_ns:
            a, b = kfs[start - 1], kfs[start]
            rel = b.cam_from_world[:3, :3] @ a.cam_from_world[:3, :3].T
            if not self.agrees(a.stamp_ns, b.stamp_ns, rel):
                break
            start -= 1
        window = kfs[start:]
        if len(window) < 2 or (newest - window[0].stamp_ns) * 1e-9 < self.config.imu_init_s:
            return []
        return window

    def place_head(self, map_id: int, first: Keyframe) -> int:
        """Place the keyframes of map ``map_id`` older than ``first`` (the initialisation
        window's first keyframe, already in the gravity-aligned world with its state) on the
        IMU, integrating back from ``first``; the frames hanging from them are placed on the
        IMU too, and the points only they see are triangulated again from their new poses.
        Returns how many keyframes were placed."""
        head = [k for k in self.map.live(map_id) if k.stamp_ns < first.stamp_ns]
        if not head or not self.covers(head[0].stamp_ns, first.stamp_ns):
            return 0
        state = self.states[first.id]
        placed: set[int] = set()
        for k in head:
            got = self.predict_back(first, k.stamp_ns)
            assert got is not None
            k.cam_from_world = inverse(got[0] @ self.rig.body_from_camera)
            self.states[k.id] = np.concatenate([got[1], state[3:9]])
            placed.add(k.id)
        self._place_frames(placed)
        self._triangulate_again(placed)
        return len(placed)

    def _place_frames(self, kf_ids: set[int]) -> None:
        """The frames hanging from keyframes ``kf_ids`` take the IMU's pose relative to their
        keyframe."""
        for rec in self.atlas.frames:
            if rec.kf not in kf_ids:
                continue
            kf = self.map.keyframes[rec.kf]
            got = self.predict_state(kf, rec.stamp_ns)
            if got is not None:
                cam_from_world = inverse(got[0] @ self.rig.body_from_camera)
                rec.cam_from_kf = cam_from_world @ inverse(kf.cam_from_world)

    def _triangulate_again(self, kf_ids: set[int]) -> None:
        """Points every observer of which is in ``kf_ids``: placed again by linear
        triangulation from those keyframes' poses (dropped when fewer than two see them or
        the result is not in front of them)."""
        cam = self.rig.camera
        k_inv = np.linalg.inv(cam.K)
        alive = np.flatnonzero(self.map.alive[: self.map.n])
        for pid in alive.tolist():
            obs = self.map.obs[pid]
            if not obs or not set(obs) <= kf_ids:
                continue
            rows = []
            for k, kp in obs.items():
                kf = self.map.keyframes[k]
                ray = k_inv @ np.array([*kf.keypoints[kp], 1.0])
                pose = kf.cam_from_world
                # Two equations per view: the point's image is along ``ray``.
                rows.append(ray[0] * pose[2] - ray[2] * pose[0])
                rows.append(ray[1] * pose[2] - ray[2] * pose[1])
            if len(rows) < 4:
                self.map.cull_point(pid)
                continue
            _u, _s, vt = np.linalg.svd(np.array(rows))
            x = vt[-1]
            if abs(x[3]) < 1e-12:
                self.map.cull_point(pid)
                continue
            x = x[:3] / x[3]
            depths = [(self.map.keyframes[k].cam_from_world @ np.append(x, 1.0))[2] for k in obs]
            if min(depths) <= 0:
                self.map.cull_point(pid)
                continue
            self.map.pos[pid] = x

    def due_refinement(self, map_id: int) -> bool:
        """Whether map ``map_id`` is due its inertial refinement (``imu_refine_s`` after its
        initialisation)."""
        if not self.active(map_id) or map_id in self._refined:
            return False
        chain = self.chain(map_id)
        init = self.inits[map_id]
        return bool(chain) and (chain[-1].stamp_ns - init.stamps_ns[-1]) * 1e-9 >= (
            self.config.imu_refine_s
        )

    def refined(self, map_id: int) -> None:
        """Map ``map_id`` had its refinement."""
        self._refined.add(map_id)
        chain = self.chain(map_id)
        state = self.states[chain[-1].id]
        first = self._first_image_ns if self._first_image_ns is not None else 0
        self.records.append(
            {
                "map": map_id,
                "kind": "refinement",
                "after_s": round((chain[-1].stamp_ns - first) * 1e-9, 3),
                "keyframes": len(chain),
                "gyro_bias": [round(float(x), 7) for x in state[3:6]],
                "accel_bias": [round(float(x), 6) for x in state[6:9]],
            }
        )

    def gravity_aligned(self, init: InertialInit) -> F64:
        """(4, 4) the similarity that takes the map's frame into the gravity-aligned metric
        world: ``s R``."""
        w = np.eye(4)
        w[:3, :3] = init.scale * init.world_from_visual
        return w

    def table(self, main: int | None) -> F64 | None:
        """(K, 10) per keyframe of map ``main``, once its IMU is initialised: stamp (ns),
        velocity and biases (:attr:`~slamcli.types.SlamResult.imu_states`); else None."""
        if main is None or not self.active(main):
            return None
        chain = self.chain(main)
        return np.array([[k.stamp_ns, *self.states[k.id]] for k in chain], dtype=np.float64)
