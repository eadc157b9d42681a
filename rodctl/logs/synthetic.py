"""A realistic synthetic run (header + step records) without the simulator.

Why: the sinks and the reader must be tested, benchmarked and looked at in Foxglove/Rerun
independently of the physics, vision and control stages. The run here has the shapes and
magnitudes of a real one — a 0.6 m rod clamped at the origin, a gripper that moves towards a
target pose, 51-point world centerlines, 100-point pixel centerlines in a 640 x 480 eye-to-hand
view, p = 6 features, a 6 x 3 Jacobian estimate — but its numbers mean nothing physically.
`arms=2` makes it a dual-arm run (q = 6): the x0 end moves too (`StepRecord.clamp`), commands
and the Jacobian have 6 columns, and every step after the first has a `jacobian_error`.
Deterministic for a given seed (numpy Generator; no global RNG).
"""

from __future__ import annotations

import cv2
import numpy as np

from rodctl.geometry import resample_polyline
from rodctl.records import RunHeader, StepRecord

_CONFIG_YAML = """\
name: synthetic
seed: {seed}
rod:
  length: 0.6
  clamp_pose: [0.0, 0.0, 0.0]
camera:
  width: 640
  height: 480
  points: 100
logging:
  image_rate_hz: 5.0
"""

#: Appended to the rod section of a dual-arm synthetic run's config.
_DUAL_ARM_YAML = """\
  arms: 2
  max_step: [0.02, 0.02, 0.1]
  clamp_arm:
    max_step: [0.005, 0.005, 0.02]
"""


def _curve(clamp: np.ndarray, grip: np.ndarray, m: int) -> np.ndarray:
    """(m, 2) cubic Hermite curve leaving the clamp along its theta and reaching the gripper
    along the gripper's theta: a rod-like shape."""
    p0, p1 = clamp[:2], grip[:2]
    scale = np.linalg.norm(p1 - p0) + 1e-9
    t0 = scale * np.array([np.cos(clamp[2]), np.sin(clamp[2])])
    t1 = scale * np.array([np.cos(grip[2]), np.sin(grip[2])])
    s = np.linspace(0.0, 1.0, m)[:, None]
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * p0 + h10 * t0 + h01 * p1 + h11 * t1


class SyntheticRun:
    """A fake run: `header` and `records(n)`.

    Args:
        seed: seed of the run's numbers.
        image_every: a camera frame every this many steps (0 = none).
        noisy_images: add sensor noise to frames (harder for PNG, like a real camera).
        p: feature dimension.
        arms: 1 (the x0 end clamped, q = 3) or 2 (dual-arm: the x0 end moves too, q = 6).
    """

    width, height = 640, 480
    focal = 700.0  # px per metre at the rod plane

    def __init__(
        self,
        seed: int = 0,
        image_every: int = 5,
        noisy_images: bool = False,
        p: int = 6,
        arms: int = 1,
    ) -> None:
        if arms not in (1, 2):
            raise ValueError(f"arms must be 1 or 2, got {arms}")
        self.rng = np.random.default_rng(seed)
        self.seed = seed
        self.image_every = image_every
        self.noisy_images = noisy_images
        self.p = p
        self.arms = arms
        self.clamp = np.array([0.0, 0.0, 0.0])
        self.home = np.array([0.55, 0.0, 0.0])
        self.target_pose = np.array([0.45, 0.18, 0.9])
        if arms == 2:  # both ends' poses: the gripper's, then the x0 end's
            self.home = np.concatenate([self.home, self.clamp])
            self.target_pose = np.concatenate([self.target_pose, [0.05, -0.04, 0.2]])
        self.W = self.rng.normal(size=(p, 100 * 2)) / 40.0
        target_world = self._world(self.target_pose)
        target_px = resample_polyline(self.project(target_world), 100)
        self.s_target = self.feature(target_px)
        self.header = RunHeader(
            run_id=f"20261123-101500_synthetic-{seed}",
            method="mfac-akf",
            config_yaml=self._config_yaml(),
            image_size=(self.width, self.height),
            clamp_pose=self.clamp.copy(),
            home_pose=self.home.copy(),
            target_centerline=target_world,
            target_pixels=target_px,
            target_feature=self.s_target.copy(),
            target_pose=self.target_pose.copy(),
            rod_length=0.6,
        )

    def _config_yaml(self) -> str:
        text = _CONFIG_YAML.format(seed=self.seed)
        if self.arms == 2:
            text = text.replace("camera:\n", _DUAL_ARM_YAML + "camera:\n", 1)
        return text

    def _world(self, pose: np.ndarray) -> np.ndarray:
        """(51, 2) the rod's world centerline for the moved ends' `pose` (x0 end first)."""
        clamp = pose[3:6] if self.arms == 2 else self.clamp
        return _curve(clamp, pose[:3], 51)

    def project(self, world: np.ndarray) -> np.ndarray:
        """(M, 2) world metres -> (M, 2) pixels (u right, v down)."""
        u = 120.0 + self.focal * world[:, 0]
        v = 0.5 * self.height - self.focal * world[:, 1]
        return np.stack([u, v], axis=1)

    def feature(self, pixels: np.ndarray) -> np.ndarray:
        """(p,) a linear 'feature' of the centred pixel centerline."""
        return self.W @ ((pixels - [320.0, 240.0]) / 100.0).ravel()

    def render(self, pixels: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB frame: light background, dark rod, optional noise."""
        img = np.full((self.height, self.width, 3), (235, 232, 225), dtype=np.uint8)
        pts = np.round(pixels * 4).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], False, (40, 40, 45), thickness=7, lineType=cv2.LINE_AA, shift=2)
        if self.noisy_images:
            noise = self.rng.normal(0.0, 2.0, size=img.shape)
            img = np.clip(img + noise, 0, 255).astype(np.uint8)
        return img

    def _command(self, k: int, phase: str, pose: np.ndarray) -> np.ndarray:
        """(q,) step k's command before the speed limit: none, a probing move, or a noisy
        quarter of the way to the target."""
        q = 3 * self.arms
        if k == 0:
            return np.zeros(q)
        if phase == "probe":
            return np.eye(q)[k - 1] * np.tile([0.01, 0.01, 0.05], self.arms)
        return 0.25 * (self.target_pose - pose) + self.rng.normal(0, 1e-3, q)

    def records(self, n: int) -> list[StepRecord]:
        """The first `n` steps: initial observation, 3 probing steps, then control."""
        out: list[StepRecord] = []
        pose = self.home.copy()
        J = self.rng.normal(size=(self.p, 3 * self.arms))
        # The speed limits: the gripper's, then (dual-arm) the x0 end's.
        lo = np.array([-0.02, -0.02, -0.1, -0.005, -0.005, -0.02][: 3 * self.arms])
        period = 0.2
        for k in range(n):
            phase = "initial" if k == 0 else ("probe" if k <= 3 else "control")
            u_raw = self._command(k, phase, pose)
            u = np.clip(u_raw, lo, -lo)
            pose = pose + u
            world = self._world(pose)
            truth_px = resample_polyline(self.project(world), 100)
            extracted = truth_px + self.rng.normal(0.0, 0.3, truth_px.shape)
            s = self.feature(extracted)
            J = J + self.rng.normal(0.0, 0.01, J.shape)
            err = np.linalg.norm(extracted - self.header.target_pixels, axis=1).mean()
            shown = self.image_every and k % self.image_every == 0
            image = self.render(truth_px) if shown else None
            out.append(
                StepRecord(
                    step=k,
                    sim_time=round(0.05 + k * period, 9),
                    phase=phase,
                    gripper=pose[:3].copy(),
                    centerline=world,
                    extracted=extracted,
                    projected_truth=truth_px,
                    u=u,
                    u_raw=u_raw,
                    s=s,
                    s_target=self.s_target.copy(),
                    T1=float(np.linalg.norm(self.s_target - s)),
                    J=J.copy(),
                    J_singular_values=np.linalg.svd(J, compute_uv=False),
                    pixel_error=float(err),
                    settled=k % 17 != 9,
                    saturated=np.abs(u_raw) > -lo,
                    clipped=bool(k == 7),
                    max_joint_gap=float(self.rng.uniform(0, 1e-5)),
                    kinetic_energy=float(self.rng.uniform(0, 1e-6)),
                    extraction_ok=k % 23 != 11,
                    extraction_note="" if k % 23 != 11 else "rod partly occluded",
                    estimator_info={
                        "alpha": float(self.rng.uniform(0.9, 1.0)),
                        "innovation": float(self.rng.normal()),
                    },
                    image=image,
                    clamp=pose[3:6].copy() if self.arms == 2 else None,
                    jacobian_error=(
                        float(self.rng.uniform(0.05, 0.5))
                        if self.arms == 2 and k > 0
                        else float("nan")
                    ),
                )
            )
        return out
