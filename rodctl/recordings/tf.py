"""End-effector poses from a tf tree: the chain from a child frame up to a world frame, each
transform interpolated at the frame times, composed, then taken as a planar pose.

A bag's `/tf` (`tf2_msgs/msg/TFMessage`) carries timed transforms parent -> child; its
`/tf_static` the transforms that do not change (each child's last one is used at every time).
Every child has one parent, so from a child frame the parents lead up to the tree's root. The
pose of a child in the world frame W (`--tf-world`, default the root) is the product
T_W,a T_a,b ... T_y,child of the transforms along that chain, each evaluated at the frame's
time: translation linear between the two transforms around it, rotation by slerp (the
shortest arc); a frame whose two neighbouring transforms of one link are further apart than
the tolerance is refused, naming the link's frame and the time. The planar pose is the
product's x, y and its yaw (the rotation about z, as for a PoseStamped).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rodctl.errors import UserError


def static_topic(tf_topic: str) -> str:
    """The static topic beside a tf topic: /tf -> /tf_static, /robot/tf -> /robot/tf_static."""
    return tf_topic + "_static" if tf_topic.endswith("tf") else "/tf_static"


@dataclass
class _Link:
    """The transforms parent -> child of one child frame: (t_ns, translation, quaternion)."""

    parent: str
    topic: str
    static: bool = True
    times: list[int] = field(default_factory=list)
    values: list[list[float]] = field(default_factory=list)  # tx, ty, tz, qx, qy, qz, qw


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions [x, y, z, w]."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors rotated by the unit quaternions (..., 4)."""
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of (K, 4) unit quaternions at fractions (K,), along the
    shortest arc (q1 is negated where q0 . q1 < 0); near-equal ones linearly, renormalised."""
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    dot = (q0 * q1).sum(axis=1)
    q1 = np.where(dot[:, None] < 0.0, -q1, q1)
    dot = np.abs(dot).clip(0.0, 1.0)
    theta = np.arccos(dot)
    s = np.sin(theta)
    near = s < 1e-9
    safe = np.where(near, 1.0, s)
    a = np.where(near, 1.0 - w, np.sin((1.0 - w) * theta) / safe)
    b = np.where(near, w, np.sin(w * theta) / safe)
    q = a[:, None] * q0 + b[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def yaw(q: np.ndarray) -> np.ndarray:
    """The rotation about z of (..., 4) quaternions [x, y, z, w] (ZYX Euler yaw)."""
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)  # scale-free


class TfTree:
    """The transforms of a tf topic and its static topic, by child frame."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.links: dict[str, _Link] = {}

    def add(self, msg: Any, log_ns: int, *, static: bool, topic: str) -> None:
        """Add a TFMessage's transforms (their header stamps; the log time where zero)."""
        for tr in msg.transforms:
            child = str(tr.child_frame_id).lstrip("/")
            parent = str(tr.header.frame_id).lstrip("/")
            link = self.links.get(child)
            if link is None:
                link = self.links[child] = _Link(parent, topic)
            elif link.parent != parent:
                raise UserError(
                    f"{topic}: child frame {child!r} has two parents, {link.parent!r} "
                    f"({link.topic}) and {parent!r}; a tf tree gives each frame one parent"
                )
            link.static = link.static and static
            s = tr.header.stamp
            t = int(s.sec) * 1_000_000_000 + int(s.nanosec)
            v, o = tr.transform.translation, tr.transform.rotation
            t = t if t > 0 else int(log_ns)
            vals = np.array([v.x, v.y, v.z, o.x, o.y, o.z, o.w], dtype=float)
            where = f"{topic}: child frame {child!r} at stamp {t / 1e9:.6f} s"
            if not np.all(np.isfinite(vals)):
                shown = ", ".join(f"{float(x):g}" for x in vals)
                raise UserError(f"{where}: the transform has non-finite values ({shown})")
            norm = float(np.linalg.norm(vals[3:]))
            if norm < 1e-9:
                raise UserError(f"{where}: the rotation quaternion is zero (no rotation defined)")
            vals[3:] /= norm  # unit quaternions, so that static links compose exactly
            link.times.append(t)
            link.values.append(vals.tolist())

    def frames(self) -> set[str]:
        return set(self.links) | {link.parent for link in self.links.values()}

    def chain(self, child: str, world: str | None) -> list[tuple[str, _Link]]:
        """The links from `child` up to `world` (default: the root), child's first.

        Raises:
            UserError: `world` is not among the child's ancestors (both are named).
        """
        out: list[tuple[str, _Link]] = []
        names = [child]
        frame = child
        while frame != world and frame in self.links:
            if frame in names[:-1]:
                raise UserError(f"{self.topic}: the tf tree has a loop through {frame!r}")
            link = self.links[frame]
            out.append((frame, link))
            frame = link.parent
            names.append(frame)
        if world is not None and frame != world:
            raise UserError(
                f"{self.topic}: child frame {child!r} is not connected to the world frame "
                f"{world!r} (its parents lead to {' -> '.join(names)}); give --tf-world one of "
                f"{', '.join(repr(n) for n in names[1:]) or 'its ancestors'}"
            )
        return out

    def poses_at(
        self,
        child: str,
        world: str | None,
        frame_ns: np.ndarray,
        t0: int,
        tolerance: float,
        bracket: Any,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The planar poses (K, 3) of `child` in `world` at the frame times inside every link's
        time span, and the mask of those frames (T,). `bracket` is `ros2._bracket`.

        Raises:
            UserError: not connected, no frame inside the spans, or a gap above `tolerance`
                around a frame in one link (the link's child frame and the time are named).
        """
        ft = (np.asarray(frame_ns, dtype=np.int64) - t0) / 1e9
        links = self.chain(child, world)
        inside = np.ones(len(ft), dtype=bool)
        #: per link, from the child up: (None: static, else its bracket of the frames, values)
        parts: list[tuple[tuple | None, np.ndarray]] = []
        for name, link in links:
            vals = np.asarray(link.values, dtype=float)
            if link.static:
                parts.append((None, vals[-1]))
                continue
            pt = (np.asarray(link.times, dtype=np.int64) - t0) / 1e9
            label = f"{link.topic} (child frame {child}): link {name!r} in {link.parent!r}"
            order = np.argsort(pt, kind="stable")
            lo, hi, w, ins = bracket(ft, pt[order], label, tolerance, "transforms")
            parts.append(((lo, hi, w, ins), vals[order]))
            inside &= ins
        k = int(inside.sum())
        if k == 0:
            raise UserError(
                f"{self.topic}: frame {child!r}: no frame lies inside the time spans of all its "
                "links' transforms"
            )
        t = np.zeros((k, 3))
        q = np.tile([0.0, 0.0, 0.0, 1.0], (k, 1))
        for how, vals in reversed(parts):  # from the world down to the child
            if how is None:
                tl, ql = np.tile(vals[:3], (k, 1)), np.tile(vals[3:], (k, 1))
            else:
                lo, hi, w, ins = how
                keep = inside[ins]  # of this link's bracketed frames, those kept by all
                lo, hi, w = lo[keep], hi[keep], w[keep]
                tl = (1.0 - w)[:, None] * vals[lo, :3] + w[:, None] * vals[hi, :3]
                ql = slerp(vals[lo, 3:], vals[hi, 3:], w)
            t = t + _rotate(q, tl)
            q = _qmul(q, ql)
        return np.column_stack([t[:, :2], np.unwrap(yaw(q))]), inside
