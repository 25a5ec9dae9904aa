"""The surface a tool presses on, as seen in its contact positions: a plane plus a compliant pad's sink.

Along a pressing direction ``n`` (unit, into the surface, world frame) the depth of the tool point
``p·n`` (m) on a plane pressed through a compliant pad or part is

    depth = offset + slope · (uv - uv₀) + compliance · press

with ``uv`` the tool point's coordinates in the plane across ``n`` (m), ``press`` the force along
``n`` (N) and ``compliance`` (m/N) in ``[0, MAX_COMPLIANCE_M_N]``: a sponge sinks ~10 mm under
20 N, so as a press relaxes the tool rises on the surface, not off it, and a swinging press moves
the tool along ``n`` without any curvature of the surface. `skills.contact` uses the model to tell
a tool on the surface from one above it; `skills.selection` uses its residual as the planarity
of a contact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

MAX_COMPLIANCE_M_N = 2.0e-3
"""Softest pad or part the model allows: 2 mm of sink per N (a sponge under a light press)."""


@dataclass(frozen=True)
class PressedSurface:
    """A plane pressed on through a compliant pad, fitted to contact positions (see the module docstring)."""

    normal: NDArray[np.float64]
    basis: NDArray[np.float64]
    """(3, 2) orthonormal axes of the plane across ``normal``."""
    uv_origin: NDArray[np.float64]
    offset_m: float
    slope: NDArray[np.float64]
    """(2,) depth change per m along ``basis`` (the plane's tilt from ``normal``)."""
    compliance_m_n: float
    residual_rms_m: float
    """RMS of the fitted positions' depth about the model, m (the surface's departure from a plane)."""

    def depth_at(self, positions: NDArray[np.float64], press: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the depth (N,) m the tool point would have ON the surface at ``positions`` (N, 3) m.

        ``press`` (N,) N is the force along the normal there; a pull (negative press) sinks nothing.
        """
        uv = positions @ self.basis - self.uv_origin
        return self.offset_m + uv @ self.slope + self.compliance_m_n * np.maximum(press, 0.0)


def pressed_surface(
    positions: NDArray[np.float64],
    press: NDArray[np.float64],
    normal: NDArray[np.float64],
    max_tilt_deg: float | None = None,
    basis: NDArray[np.float64] | None = None,
) -> PressedSurface:
    """Fit the pressed-surface model to contact ``positions`` (M, 3) m pressing ``press`` (M,) N along unit ``normal``.

    Least squares; the compliance is clipped to ``[0, MAX_COMPLIANCE_M_N]`` and the plane refitted
    with it. ``max_tilt_deg`` bounds the plane's tilt from ``normal`` (a steeper plane could hold
    an arc drawn in a vertical plane, but nobody presses on it); a straight path leaves the
    sideways tilt free, and least squares takes the smallest. ``basis`` (3, 2) orthonormal axes across
    ``normal`` that the slopes refer to (default: any).
    """
    if basis is None:
        basis = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    depth = positions @ normal
    uv_origin = (positions @ basis).mean(axis=0)
    uv = positions @ basis - uv_origin
    design = np.column_stack([np.ones(depth.size), uv, press])
    coefficients, *_ = np.linalg.lstsq(design, depth, rcond=1e-9)
    compliance = float(np.clip(coefficients[3], 0.0, MAX_COMPLIANCE_M_N))
    on_plane = depth - compliance * press
    plane, *_ = np.linalg.lstsq(design[:, :3], on_plane, rcond=1e-9)
    slope = plane[1:]
    if max_tilt_deg is not None:
        slope = slope * min(1.0, np.tan(np.radians(max_tilt_deg)) / max(float(np.linalg.norm(slope)), 1e-12))
    offset = float(np.mean(on_plane - uv @ slope))
    residual = on_plane - offset - uv @ slope
    return PressedSurface(
        normal=normal,
        basis=basis,
        uv_origin=uv_origin,
        offset_m=offset,
        slope=slope,
        compliance_m_n=compliance,
        residual_rms_m=float(np.sqrt(np.mean(residual**2))),
    )
