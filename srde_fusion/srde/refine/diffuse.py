"""The diffuse light that further known lamps shed on the samples.

A lamp whose highlight is not in the fitting windows still lights the surface there:
its diffuse term ``cos(theta_i) / r^2`` varies over the surface, and the windows of
different views lie on different parts of it (the highlight moves over the surface
from view to view), so a constant level does not absorb it. Left out, it biased faces
lit by another face's lamp: on the faceted benchmark five faces refined from their true
planes ended 0.07-0.17 px off (four to five standard errors), and 0.002-0.019 px with the
other lamp's diffuse term modelled (0.0002-0.006 px on images rendered without that lamp).

Each lamp adds one basis vector to the intensities (its brightness times the surface's
albedo is not known) and nothing to the shape of the fit. Its geometry reuses the main
light's ray algebra (:class:`~.reflection.PlaneReflection`): with ``X = C + t k`` on the
plane, ``|L - X|^2 = a - 2 t b + t^2 q`` and ``cos(theta_i) = (n . L - c) / r``.
"""

from __future__ import annotations

import numpy as np

from .layout import N_PLANE
from .reflection import PlaneReflection

__all__ = ["DiffuseLights"]


class DiffuseLights:
    """The diffuse terms of further lights at a model's points, and their plane slopes.

    Parameters
    ----------
    reflection : PlaneReflection
        The main light's geometry of the model's points (rays, camera centres, the
        plane's parametrisation); must be valid.
    lights_m : numpy.ndarray, (M, 3)
        The further lights, array frame, metres.
    reduce : callable, optional
        The model's average over each sample's points, ``(..., S * P) -> (..., P)``
        (:meth:`~.model.LobeModel.reduce`); the points are the samples by default.

    Each light's term is normalised to a median of 1 over the points at the initial
    plane, as the main light's (a light behind the initial plane keeps its raw scale;
    it lights nothing there).
    """

    def __init__(self, reflection: PlaneReflection, lights_m: np.ndarray,
                 reduce=None) -> None:
        self.reflection = reflection
        self.reduce = (lambda values, out=None: values) if reduce is None else reduce
        self.lights_m = np.asarray(lights_m, dtype=np.float64).reshape(-1, 3)
        to_light = self.lights_m[:, None, :] - reflection.camera_t.T[None]   # (M, P, 3)
        self.a = np.einsum("mpi,mpi->mp", to_light, to_light)
        self.b = np.einsum("mpi,ip->mp", to_light, reflection.ray_t)
        self.scale = np.ones(len(self.lights_m))
        self._key: bytes | None = None
        self._value: tuple | None = None
        start = self._terms(np.zeros(N_PLANE))
        if start is not None:
            medians = np.median(start[-1], axis=1)
            self.scale = np.where(medians > 0.0, 1.0 / np.where(medians > 0.0, medians, 1.0),
                                  1.0)
            self._key = None

    def __len__(self) -> int:
        return len(self.lights_m)

    def _terms(self, plane_params: np.ndarray):
        """Terms ``(M, P)`` and the intermediates of their slopes, or None (invalid plane)."""
        key = plane_params[:N_PLANE].tobytes()
        if self._key == key:
            return self._value
        reflection = self.reflection
        # The main light's geometry of the plane (cached there) has the rays' algebra.
        g = reflection.at(plane_params)
        if g is None:
            value = None
        else:
            n, t, nk = g.normal, g.t, g.nk
            c = float(reflection.planes(plane_params[None, :N_PLANE])[1][0])
            height = self.lights_m @ n - c                                # (M,)
            lit = height > 0.0  # a light behind the plane lights none of it
            r2 = t * reflection.q                                         # (P,)
            r2 = r2 - 2.0 * self.b                                        # (M, P)
            r2 *= t
            r2 += self.a
            r = np.sqrt(r2)
            inv_r3 = np.multiply(r2, r, out=r2)
            np.reciprocal(inv_r3, out=inv_r3)
            terms = inv_r3 * np.where(lit, height, 0.0)[:, None]
            terms *= self.scale[:, None]
            value = (self.reduce(terms), n, t, nk, height, lit, r, inv_r3, terms)
        self._key, self._value = key, value
        return value

    def at(self, plane_params: np.ndarray) -> np.ndarray | None:
        """Each light's diffuse term ``(M, P)`` for plane parameters ``(3,)``, reduced.

        Averaged over each sample's points by ``reduce``. None where the main light's
        geometry is (a plane seen from behind, or with the main light behind it).
        """
        value = self._terms(plane_params)
        return None if value is None else value[0]

    def slopes(self, plane_params: np.ndarray, intensities: np.ndarray, free: np.ndarray,
               out: np.ndarray) -> np.ndarray:
        """Add the slopes of ``sum_m intensities[m] * term_m`` by ``free``'s plane parameters.

        ``out`` ``(len(free), P)``, at the samples, is added to (rows of shape parameters
        untouched) and returned. ``cos_i / r^2 = h / r^3`` with ``h = n . L - c``; ``r``
        moves with the ray parameter ``t`` (``dr = (t q - b) / r dt``) and
        ``t = (c - n . C) / (n . k)``.
        """
        value = self._terms(plane_params)
        planes = [(row, index) for row, index in enumerate(free) if index < N_PLANE]
        if value is None or not planes:
            return out
        _, n, t, nk, height, lit, r, inv_r3, _ = value
        weight = np.where(lit, intensities * self.scale, 0.0)                 # (M,)
        # by h: 1 / r^3 per light; by t: -3 h / r^4 dr/dt
        on_height = weight[:, None] * inv_r3                                  # (M, P)
        rho = (t * self.reflection.q - self.b) / r
        on_t = (-3.0 * (weight * height)[:, None]) * inv_r3 / r * rho
        on_cam = on_t.sum(axis=0) / nk
        on_nk = -on_cam * t
        directions = self.reflection.directions(plane_params)
        points = np.zeros((len(planes), on_cam.size))
        for slope, (_, index) in zip(points, planes, strict=True):
            dn, dc = directions[index]
            # d h = dn . L - dc; d(c - n . C) = dc - dn . C; d(n . k) = dn . k
            slope += dc * (on_cam - on_height.sum(axis=0))
            if dn.any():
                slope += (self.lights_m @ dn) @ on_height
                slope -= on_cam * (dn @ self.reflection.camera_t)
                slope += on_nk * (dn @ self.reflection.ray_t)
        out[[row for row, _ in planes]] += self.reduce(points)
        return out
