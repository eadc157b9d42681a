"""Features that are least-squares coefficients of a fixed basis in normalised arc length.

Bézier control points and half-range cosine coefficients are both linear fits
``c(rho) ~= Phi(rho) A`` of the arc-length-resampled centerline, with ``Phi`` (N, K) fixed once N
and the basis are known. The fit ``A = pinv(Phi) c`` is then a (K, N) matrix product, and the
reconstruction ``Phi A`` is the orthogonal projection of the resampled centerline onto the span of
the basis: its residual *is* the truncation error of the representation.
"""

from __future__ import annotations

import numpy as np

from rodctl import fixedla as fla
from rodctl.features.geometry import check_centerlines, resample_uniform


class LinearBasisFeatureMap:
    """Feature s = vec_rows(pinv(Phi) c_resampled) of shape (2K,), in pixels.

    Subclasses pass the basis matrix. The coefficient matrix is (K, 2) (one row per basis
    function, columns u and v) and the feature is that matrix flattened row-major, so
    ``s.reshape(K, 2)[k]`` is the k-th coefficient as a pixel vector.

    Attributes:
        dim: feature dimension p = 2K.
        points: the N the map expects.
        kind: the config `type` of the map.
        units: "px": every component is in pixels.
        scale: (p,) typical magnitude of a component's variation; ones (pixel units throughout).
    """

    kind = "linear"
    units = "px"

    def __init__(self, basis: np.ndarray) -> None:
        self._basis = np.ascontiguousarray(basis, dtype=np.float64)  # (N, K)
        # Fixed-order QR (rodctl.fixedla), not LAPACK's SVD: the fit matrix must be the same
        # bits on every machine, or so is no feature (docs/reproducibility.md).
        self._pinv = np.ascontiguousarray(fla.pinv_tall(self._basis))  # (K, N)
        self._rho = np.linspace(0.0, 1.0, self._basis.shape[0])
        self.points = int(self._basis.shape[0])
        self.terms = int(self._basis.shape[1])
        self.dim = 2 * self.terms
        self.scale = np.ones(self.dim)

    def encode(self, centerline_px: np.ndarray) -> np.ndarray:
        """(N, 2) pixels, clamp end first -> (p,) float64 coefficients. Deterministic."""
        return self.encode_batch(check_centerlines(centerline_px, self.points, batch=False))[0]

    def encode_batch(self, centerlines_px: np.ndarray) -> np.ndarray:
        """(B, N, 2) pixels -> (B, p)."""
        arr = check_centerlines(centerlines_px, self.points, batch=True)
        uniform = resample_uniform(arr, self._rho)  # (B, N, 2)
        coeffs = np.einsum("kn,bnc->bkc", self._pinv, uniform)  # (B, K, 2)
        return coeffs.reshape(arr.shape[0], self.dim)

    def decode(self, s: np.ndarray) -> np.ndarray:
        """Feature (p,) or (B, p) -> the represented curve at N uniform arc lengths, (N, 2) or
        (B, N, 2) pixels."""
        s = np.asarray(s, dtype=np.float64)
        coeffs = s.reshape(*s.shape[:-1], self.terms, 2)
        return np.einsum("nk,...kc->...nc", self._basis, coeffs)

    def reconstruction_error(self, centerlines_px: np.ndarray) -> np.ndarray:
        """Truncation error of the representation per shape.

        Args:
            centerlines_px: (B, N, 2) pixels.

        Returns:
            (B, N) distance in pixels between each arc-length-resampled point and its
            reconstruction.
        """
        arr = check_centerlines(centerlines_px, self.points, batch=True)
        uniform = resample_uniform(arr, self._rho)
        recon = self.decode(self.encode_batch(arr))
        return np.linalg.norm(recon - uniform, axis=-1)
