"""Loop closing of the visual pipeline: places recognised again close loops or merge maps.

Each new keyframe's bag of words is queried against the database (:mod:`.places`);
candidates must score above the keyframe's worst covisible neighbour, be consistent over
``loop_consistency`` consecutive keyframes, and pass geometric verification (PnP for RGB-D,
Sim(3) for monocular) followed by a guided search. A verified loop fuses the duplicated points
and optimises the essential graph (spanning tree, strong covisibility edges and loops; SE(3) or
Sim(3), GTSAM), then a global bundle adjustment. A place recognised in another map merges the
two maps (ORB-SLAM's LoopClosing).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.geometry import inverse
from slamcli.pipelines.visual.atlas import Keyframe, SparseMap
from slamcli.pipelines.visual.bundle import BundleAdjuster
from slamcli.pipelines.visual.inertial import Inertial
from slamcli.pipelines.visual.local_mapping import LocalMapping
from slamcli.pipelines.visual.parts import Part, Shared
from slamcli.pipelines.visual.search import in_view, project_match
from slamcli.types import PinholeCamera
from slamcli.vision.matching import TH_HIGH, match_ratio
from slamcli.vision.pnp import absolute_pose, pose_change, refine_pose

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


class LoopClosing(Part):
    """Loops and merges found from each new keyframe (:meth:`detect`); ``records`` holds one
    record per verified candidate (type, keyframes, frames, score, inliers, accepted, reason,
    and the correction it made); ``doubts`` says why the run's result may be wrong (a loop
    refused because its correction was implausible)."""

    def __init__(self, shared: Shared, mapper: LocalMapping, ba: BundleAdjuster) -> None:
        super().__init__(shared)
        self.mapper, self.ba = mapper, ba
        self.records: list[dict[str, Any]] = []
        self.doubts: list[str] = []
        self._consistent: list[tuple[set[int], int]] = []
        self.inertial: Inertial | None = None

    def detect(self, kf: Keyframe) -> None:
        """Place recognition for a new keyframe; verified candidates close a loop (same map)
        or merge two maps."""
        db = self.places.db
        if kf.bow is None or (len(self.map.live(kf.map_id)) < 10 and len(self.atlas.maps) < 2):
            self._consistent = []
            return
        covis = self.map.covisible(kf)
        connected = {k for k, _ in covis} | {kf.id}
        voc = db.vocabulary
        scores = [
            voc.score(kf.bow, self.map.keyframes[k].bow)
            for k, _ in covis[:30]
            if self.map.keyframes[k].bow is not None
        ]
        min_score = min(scores) if scores else 0.0
        results = {
            k: s
            for k, s in db.query(kf.bow, exclude=connected)
            if s >= min_score
            and not self.map.keyframes[k].culled
            # Keyframes just made are neighbours in time, not a revisited place.
            and not (self.map.keyframes[k].map_id == kf.map_id and kf.id - k < 10)
        }
        if not results:
            self._consistent = []
            return
        # Accumulate each candidate's score over its best neighbours; keep the groups close to
        # the best (ORB-SLAM's DetectLoopCandidates).
        groups = []
        for k, s in sorted(results.items(), key=lambda ks: (-ks[1], ks[0])):
            nbs = [n for n, _ in self.map.covisible(self.map.keyframes[k])[:10]]
            acc = s + sum(results.get(n, 0.0) for n in nbs)
            best = max(
                [(results.get(n, 0.0), n) for n in nbs] + [(s, k)], key=lambda x: (x[0], -x[1])
            )
            groups.append((acc, best[1], best[0], {k, *nbs}))
        top = max(g[0] for g in groups)
        groups = [g for g in groups if g[0] >= 0.75 * top]
        # Temporal consistency over consecutive keyframes.
        previous = self._consistent
        consistent: list[tuple[set[int], int]] = []
        ready: list[tuple[int, float]] = []
        for _acc, cand, score, group in groups:
            count = 0
            for prev_group, prev_count in previous:
                if group & prev_group:
                    count = max(count, prev_count + 1)
            consistent.append((group, count))
            if count + 1 >= self.config.loop_consistency and cand not in {c for c, _ in ready}:
                ready.append((cand, score))
        self._consistent = consistent
        for cand, score in ready[:3]:
            if self._verify_and_close(kf, self.map.keyframes[cand], score):
                self._consistent = []
                return

    def _verify_and_close(self, kf: Keyframe, cand: Keyframe, score: float) -> bool:
        """Verify a loop candidate geometrically and close the loop (or merge the maps)."""
        merge = cand.map_id != kf.map_id
        record: dict[str, Any] = {
            "type": "merge" if merge else "loop",
            "keyframes": [cand.id, kf.id],
            "frames": [cand.frame, kf.frame],
            "score": round(float(score), 4),
            "inliers": 0,
            "accepted": False,
            "reason": "",
        }
        self.records.append(record)
        scale = 1.0
        # A monocular map is metric once its IMU is initialised: its loops are rigid.
        similarity = self.rig.mono and not (
            self.inertial is not None
            and self.inertial.active(kf.map_id)
            and self.inertial.active(cand.map_id)
        )
        if similarity:
            found = self._loop_sim3(kf, cand, record)
            if found is None:
                return False
            corrected, scale = found
            record["scale"] = round(scale, 5)
        else:
            pose = self._loop_pose(kf, cand, record)
            if pose is None:
                return False
            corrected = pose
        m, deg = pose_change(inverse(kf.cam_from_world), inverse(corrected))
        record["correction_m"] = round(m, 5)
        record["correction_deg"] = round(deg, 4)
        if not merge:
            doubt = self._implausible(kf, cand, m, deg, scale)
            if doubt is not None:
                record["reason"] = f"implausible: {doubt}"
                self.doubts.append(
                    f"a loop between frames {cand.frame} and {kf.frame} was refused: {doubt}; "
                    "the map had drifted that far or the place was mistaken, and the trajectory "
                    f"after frame {cand.frame} may be wrong"
                )
                return False
        record["accepted"] = True
        record["reason"] = "verified"
        if merge:
            self._merge_maps(kf, cand, corrected, scale)
            # The maps are one now, kf already where the loop puts it.
            corrected, scale = kf.cam_from_world.copy(), 1.0
        if similarity:
            self._close_loop_sim3(kf, cand, corrected, scale)
        else:
            self._close_loop(kf, cand, corrected)
        return True

    def _implausible(
        self, kf: Keyframe, cand: Keyframe, m: float, deg: float, scale: float
    ) -> str | None:
        """Why a loop's correction (``m`` in map units, ``deg``, and for a monocular map
        ``scale``) is more than the drift the map can have gathered since ``cand``, or None.

        Drift grows with the path travelled: the translation may be at most ``loop_max_drift``
        of the path of the keyframes between the two, the rotation ``loop_max_rotation_deg``,
        the scale ``loop_max_scale_change`` either way. A loop needing more is no drift
        correction: either tracking had already failed, or the place was mistaken, and
        closing it would bend a good map to fit a bad match."""
        cfg = self.config
        if self.rig.mono and not (
            1 / cfg.loop_max_scale_change <= scale <= cfg.loop_max_scale_change
        ):
            return (
                f"it needs the map rescaled by {scale:.3g} "
                f"(at most {cfg.loop_max_scale_change:g} either way)"
            )
        if deg > cfg.loop_max_rotation_deg:
            return f"it turns the map by {deg:.1f} deg (at most {cfg.loop_max_rotation_deg:g})"
        between = [k for k in self.map.live(kf.map_id) if cand.id <= k.id < kf.id] + [kf]
        centres = np.stack([k.center for k in between])
        path = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())
        if m > cfg.loop_max_drift * path:
            return (
                f"it moves the map by {m:.3g} after a path of {path:.3g} "
                f"(at most {cfg.loop_max_drift:g} of it)"
            )
        return None

    def _loop_sim3(
        self, kf: Keyframe, cand: Keyframe, record: dict[str, Any]
    ) -> tuple[F64, float] | None:
        """Monocular loop verification: the similarity between the two keyframes' point
        clouds by RANSAC over matched map points (scale drifts in a monocular map), then a
        guided search of the candidate's neighbourhood with the pose it implies. Returns
        kf's corrected ``cam_from_world`` in the candidate's map and the scale that takes kf's
        map units to the candidate's."""
        from slamcli.geometry.align import umeyama

        cam = self.rig.camera
        a = np.flatnonzero(cand.point_ids >= 0)
        b = np.flatnonzero(kf.point_ids >= 0)
        pairs = match_ratio(cand.descriptors[a], kf.descriptors[b], 0.75, TH_HIGH)
        if len(pairs) < 20:
            record["reason"] = f"{len(pairs)} appearance matches (need 20)"
            return None
        ia, ib = a[pairs[:, 0]], b[pairs[:, 1]]
        pa = self.map.pos[cand.point_ids[ia]]
        pb = self.map.pos[kf.point_ids[ib]]
        ca = pa @ cand.cam_from_world[:3, :3].T + cand.cam_from_world[:3, 3]
        cb = pb @ kf.cam_from_world[:3, :3].T + kf.cam_from_world[:3, 3]
        sig_a = self.map.sigma[cand.octaves[ia]]
        sig_b = self.map.sigma[kf.octaves[ib]]
        rng = np.random.default_rng(self.config.seed)
        best: tuple[int, NDArray[np.bool_]] = (0, np.zeros(len(pairs), bool))
        for _ in range(300):
            pick = rng.choice(len(pairs), 3, replace=False)
            try:
                r, t, sc = umeyama(cb[pick], ca[pick], with_scale=True)
            except InputError:
                continue
            ok = self._sim3_inliers(cam, r, t, sc, ca, cb, cand, kf, ia, ib, sig_a, sig_b)
            n = int(np.count_nonzero(ok))
            if n > best[0]:
                best = (n, ok)
        if best[0] < 20:
            record["reason"] = f"Sim(3) RANSAC found {best[0]} inliers (need 20)"
            return None
        r, t, sc = umeyama(cb[best[1]], ca[best[1]], with_scale=True)
        # cand_from_kf as a similarity; kf's camera in cand's world, for projection.
        cand_from_kf = np.eye(4)
        cand_from_kf[:3, :3] = r
        cand_from_kf[:3, 3] = t
        rigid = np.eye(4)
        rigid[:3, :3] = r.T
        rigid[:3, 3] = -r.T @ t
        pose = rigid @ cand.cam_from_world
        found = self._guided_loop_check(kf, cand, pose, record, scaled=False)
        return None if found is None else (found, float(sc))

    def _sim3_inliers(
        self,
        cam: PinholeCamera,
        r: F64,
        t: F64,
        sc: float,
        ca: F64,
        cb: F64,
        cand: Keyframe,
        kf: Keyframe,
        ia: I64,
        ib: I64,
        sig_a: F64,
        sig_b: F64,
    ) -> NDArray[np.bool_]:
        """Correspondences whose points reproject within the χ² gate both ways."""
        in_a = sc * cb @ r.T + t
        in_b = (ca - t) @ r / sc
        ok = (in_a[:, 2] > 0) & (in_b[:, 2] > 0)
        err = np.full(len(ca), np.inf)
        za, zb = np.where(ok, in_a[:, 2], 1.0), np.where(ok, in_b[:, 2], 1.0)
        ua = np.stack([cam.fx * in_a[:, 0] / za + cam.cx, cam.fy * in_a[:, 1] / za + cam.cy], 1)
        ub = np.stack([cam.fx * in_b[:, 0] / zb + cam.cx, cam.fy * in_b[:, 1] / zb + cam.cy], 1)
        ea = np.sum((ua - cand.keypoints[ia]) ** 2, axis=1) / sig_a**2
        eb = np.sum((ub - kf.keypoints[ib]) ** 2, axis=1) / sig_b**2
        err = np.where(ok, np.maximum(ea, eb), np.inf)
        return np.asarray(err < 9.21, dtype=bool)

    def _close_loop_sim3(self, kf: Keyframe, cand: Keyframe, corrected: F64, scale: float) -> None:
        """ORB-SLAM's monocular CorrectLoop: kf and its neighbours move to the loop's
        similarity, their points with them; the essential graph is optimised on Sim(3)
        (GTSAM), every keyframe's points follow its scale, then a global bundle adjustment."""
        from slamcli.graphs.pose_graph import Edge, optimize_sim3

        self.ba.settle()
        map_id = cand.map_id
        kfs = self.map.live(map_id)
        index = {k.id: i for i, k in enumerate(kfs)}
        connected = [kf] + [self.map.keyframes[k] for k, _ in self.map.covisible(kf)]
        connected = [k for k in connected if k.map_id == map_id and k.id in index]
        old = {k.id: inverse(k.cam_from_world) for k in kfs}  # world_from_cam, rigid
        # Similarities world_from_node: kf's corrected one has the loop's scale (its map units
        # are 1/scale of the candidate's).
        sim = {k.id: old[k.id].copy() for k in kfs}
        sc = {k.id: 1.0 for k in kfs}
        kf_new = inverse(corrected)
        for k in connected:
            rel = kf.cam_from_world @ old[k.id]  # kf_from_k, rigid, kf's units
            m = kf_new.copy()
            m[:3, :3] *= scale
            m = m @ rel
            s_k = float(np.cbrt(np.linalg.det(m[:3, :3])))
            pose = np.eye(4)
            pose[:3, :3] = m[:3, :3] / s_k
            pose[:3, 3] = m[:3, 3]
            sim[k.id], sc[k.id] = pose, s_k
        group = {cand.id} | {k for k, _ in self.map.covisible(cand)[:10]}
        extra = [(kf.id, cand.id, "loop")] + [
            (k.id, g, "loop")
            for k in connected
            for g in sorted(group)
            if g in index
            and any(g in self.map.obs[p] for p in k.point_ids[k.point_ids >= 0][:50].tolist())
        ]
        edges: list[Edge] = []
        for a, b, kind in self.map.essential_links(kfs, extra):
            # Loops are measured by the corrected similarities, the rest by the old poses.
            if kind == "loop":
                wa, wb = _sim_matrix(sim[a], sc[a]), _sim_matrix(sim[b], sc[b])
            else:
                wa, wb = old[a], old[b]
            rel = np.linalg.inv(wa) @ wb
            s_ab = float(np.cbrt(np.linalg.det(rel[:3, :3])))
            r = np.eye(4)
            r[:3, :3] = rel[:3, :3] / s_ab
            r[:3, 3] = rel[:3, 3]
            edges.append(Edge(index[a], index[b], r, scale=s_ab, kind=kind))
        kf.loop_edges.add(cand.id)
        cand.loop_edges.add(kf.id)
        poses = np.stack([sim[k.id] for k in kfs])
        scales = np.array([sc[k.id] for k in kfs])
        result = optimize_sim3(poses, scales, edges, fixed=(index[cand.id],))
        assert result.scales is not None
        # Points follow their reference keyframe: into its old frame, out through the new
        # similarity.
        ids = np.flatnonzero(
            self.map.alive[: self.map.n] & (self.map.map_id[: self.map.n] == map_id)
        )
        for pid in ids.tolist():
            ref = int(self.map.ref_kf[pid])
            if ref not in index:
                ref = next((k for k in self.map.obs[pid] if k in index), -1)
                if ref < 0:
                    continue
                self.map.ref_kf[pid] = ref
            i = index[ref]
            local = self.map.keyframes[ref].cam_from_world
            p = local[:3, :3] @ self.map.pos[pid] + local[:3, 3]
            w = result.poses[i]
            self.map.pos[pid] = result.scales[i] * (w[:3, :3] @ p) + w[:3, 3]
        for k in kfs:
            k.cam_from_world = inverse(result.poses[index[k.id]])
        # Frames hang from their keyframe in its units: those change by its scale.
        self.atlas.rescale_frames({k: result.scales[i] for k, i in index.items()})
        # Duplicated points of the loop are fused into the corrected keyframes.
        loop_ids = np.unique(
            np.concatenate([self.map.keyframes[g].point_ids for g in sorted(group)])
        )
        loop_ids = loop_ids[(loop_ids >= 0)]
        loop_ids = loop_ids[self.map.alive[loop_ids]]
        for k in connected:
            self.mapper.fuse_into(k, loop_ids, radius=4.0)
        self.stats.counts["essential_graph_optimisations"] += 1
        if self.config.global_ba:
            self.ba.global_ba(map_id)

    def _loop_pose(self, kf: Keyframe, cand: Keyframe, record: dict[str, Any]) -> F64 | None:
        """``cam_from_world`` of ``kf`` in ``cand``'s map: PnP on the candidate's points, then
        a guided search of the candidate's neighbourhood; None when it does not hold."""
        cam = self.rig.camera
        has = np.flatnonzero(cand.point_ids >= 0)
        pairs = match_ratio(cand.descriptors[has], kf.descriptors, 0.75, TH_HIGH)
        if len(pairs) < 20:
            record["reason"] = f"{len(pairs)} appearance matches (need 20)"
            return None
        pids = cand.point_ids[has[pairs[:, 0]]]
        est = absolute_pose(
            cam,
            kf.keypoints[pairs[:, 1]],
            self.map.pos[pids],
            threshold_px=self.config.pnp_threshold_px,
            min_inliers=20,
            seed=self.config.seed,
        )
        if est is None:
            record["reason"] = "PnP found fewer than 20 inliers"
            return None
        return self._guided_loop_check(kf, cand, est.cam_from_world, record, scaled=True)

    def _guided_loop_check(
        self, kf: Keyframe, cand: Keyframe, pose: F64, record: dict[str, Any], *, scaled: bool
    ) -> F64 | None:
        """Search the points of ``cand`` and its neighbours in ``kf`` from ``pose`` (kf's
        ``cam_from_world`` in cand's map) and refine it; the refined pose when at least
        ``loop_min_inliers`` points agree, else None (the reason in ``record``). Without
        ``scaled`` (a monocular map of another scale) the points' distance ranges are not used."""
        cam = self.rig.camera
        group = [cand] + [self.map.keyframes[k] for k, _ in self.map.covisible(cand)[:10]]
        ids = np.unique(np.concatenate([g.point_ids[g.point_ids >= 0] for g in group]))
        ids = ids[self.map.alive[ids] & (self.map.map_id[ids] == cand.map_id)]
        if scaled:
            visible, dist = in_view(self.rig.camera, self.map, pose, ids)
            ids, dist = ids[visible], dist[visible]
        else:
            z = self.map.pos[ids] @ pose[2, :3] + pose[2, 3]
            ids = ids[z > 0]
            dist = np.linalg.norm(self.map.pos[ids] - inverse(pose)[:3, 3], axis=1)
        octv = self.map.predict_octave(ids, dist)
        pairs = project_match(
            self.rig.camera,
            self.map.sigma,
            kf,
            pose,
            self.map.pos[ids],
            self.map.desc[ids],
            octv,
            7.5,
            ratio=0.9,
        )
        record["inliers"] = len(pairs)
        if len(pairs) < self.config.loop_min_inliers:
            record["reason"] = f"{len(pairs)} points matched by the guided search"
            return None
        ref = refine_pose(
            cam,
            pose,
            kf.keypoints[pairs[:, 1]],
            self.map.pos[ids[pairs[:, 0]]],
            sigma_px=self.map.sigma[kf.octaves[pairs[:, 1]]],
        )
        record["inliers"] = 0 if ref is None else ref.num_inliers
        if ref is None or ref.num_inliers < self.config.loop_min_inliers:
            record["reason"] = (
                f"{record['inliers']} inliers after refinement "
                f"(need {self.config.loop_min_inliers})"
            )
            return None
        return ref.cam_from_world

    def _merge_maps(self, kf: Keyframe, cand: Keyframe, corrected: F64, scale: float) -> None:
        """Bring the newer of the two keyframes' maps into the older one's frame (by the
        loop's rigid transform, or similarity for monocular maps) and relabel it."""
        self.ba.settle()
        old_id, new_id = cand.map_id, kf.map_id
        keep, gone = min(old_id, new_id), max(old_id, new_id)
        # A point of kf's map, in kf's camera, times scale, is where the candidate's map
        # sees it from the corrected pose.
        scaled = np.diag([scale, scale, scale, 1.0]) @ kf.cam_from_world
        w: F64 = inverse(corrected) @ scaled
        if keep == new_id:  # the candidate's map is the newer one: move it instead
            w = np.asarray(np.linalg.inv(w), dtype=np.float64)
        self.atlas.merge(keep, gone, w, (cand.id, kf.id))

    def _close_loop(self, kf: Keyframe, cand: Keyframe, corrected: F64) -> None:
        """ORB-SLAM's CorrectLoop on SE(3): move kf and its neighbours to the loop's pose,
        fuse the duplicated points, optimise the essential graph and adjust globally."""
        from slamcli.graphs.pose_graph import Edge, optimize_se3

        self.ba.settle()
        map_id = cand.map_id
        connected = [kf] + [self.map.keyframes[k] for k, _ in self.map.covisible(kf)]
        connected = [k for k in connected if k.map_id == map_id]
        before = {k.id: k.cam_from_world.copy() for k in self.map.live(map_id)}
        delta = inverse(kf.cam_from_world) @ corrected  # applied on the world side
        moved: set[int] = set()
        for k in connected:
            new = k.cam_from_world @ delta
            pids = k.point_ids[k.point_ids >= 0]
            pids = np.array([p for p in pids.tolist() if p not in moved], np.int64)
            if pids.size:
                t = inverse(new) @ k.cam_from_world
                self.map.pos[pids] = self.map.pos[pids] @ t[:3, :3].T + t[:3, 3]
                moved.update(pids.tolist())
            k.cam_from_world = new
        # Fuse the loop's points into the corrected keyframes.
        group = [cand] + [self.map.keyframes[k] for k, _ in self.map.covisible(cand)[:10]]
        loop_ids = np.unique(np.concatenate([g.point_ids[g.point_ids >= 0] for g in group]))
        loop_ids = loop_ids[self.map.alive[loop_ids]]
        for k in connected:
            self.mapper.fuse_into(k, loop_ids, radius=4.0)
        kf.loop_edges.add(cand.id)
        cand.loop_edges.add(kf.id)
        # Essential graph: spanning tree, strong covisibility, loops.
        kfs = self.map.live(map_id)
        index = {k.id: i for i, k in enumerate(kfs)}
        init = {k.id: k.cam_from_world.copy() for k in kfs}
        old_or_new = {k: before.get(k, init[k]) for k in init}
        group_ids = {g.id for g in group}
        extra = [
            (k.id, nb, "loop")
            for k in connected
            for nb, _w in self.map.covisible(k)
            if nb in group_ids
        ]
        edges: list[Edge] = []
        for a, b, kind in self.map.essential_links(kfs, extra):
            # Loops are measured by the corrected poses, the rest by the poses before it.
            poses = init if kind == "loop" else old_or_new
            edges.append(Edge(index[a], index[b], poses[a] @ inverse(poses[b]), kind=kind))
        first = kfs[0].id
        world_from = np.stack([inverse(init[k.id]) for k in kfs])
        result = optimize_se3(world_from, edges, fixed=(index[first],))
        corrected_poses = result.poses
        if self.inertial is not None and self.inertial.active(map_id):
            unmoved = np.stack([inverse(before.get(k.id, init[k.id])) for k in kfs])
            corrected_poses = self.inertial.keep_gravity(kfs, unmoved, result.poses)
        for k in kfs:
            k.cam_from_world = inverse(corrected_poses[index[k.id]])
        # Points follow the keyframe they were made in (or any that sees them).
        ids = np.flatnonzero(
            self.map.alive[: self.map.n] & (self.map.map_id[: self.map.n] == map_id)
        )
        for pid in ids.tolist():
            ref = int(self.map.ref_kf[pid])
            if ref not in index:
                views = self.map.obs[pid]
                ref = next((k for k in views if k in index), -1)
                if ref < 0:
                    continue
                self.map.ref_kf[pid] = ref
            t = inverse(self.map.keyframes[ref].cam_from_world) @ init[ref]
            self.map.pos[pid] = t[:3, :3] @ self.map.pos[pid] + t[:3, 3]
        self.stats.counts["essential_graph_optimisations"] += 1
        if self.config.global_ba:
            self.ba.global_ba(map_id)


def _sim_matrix(pose: F64, scale: float) -> F64:
    """The 4x4 similarity [[scale R, t], [0, 1]] of a rigid pose and a scale."""
    m = pose.copy()
    m[:3, :3] = pose[:3, :3] * scale
    return m


def essential_graph(
    smap: SparseMap, kfs: list[Keyframe], body_from_camera: F64 | None = None
) -> list[Any]:
    """The essential graph of keyframes ``kfs`` (edges between their indices): spanning tree,
    strong covisibility (100 shared points) and loop edges, measured by their poses (of the
    body, when the camera sits at ``body_from_camera`` on it)."""
    from slamcli.graphs.pose_graph import Edge

    b = (
        None
        if body_from_camera is None or np.array_equal(body_from_camera, np.eye(4))
        else (body_from_camera)
    )
    index = {k.id: i for i, k in enumerate(kfs)}
    edges: list[Edge] = []
    for a, c, kind in smap.essential_links(kfs):
        rel = smap.keyframes[a].cam_from_world @ inverse(smap.keyframes[c].cam_from_world)
        if b is not None:
            rel = b @ rel @ inverse(b)
        edges.append(Edge(index[a], index[c], rel, kind=kind))
    return edges
