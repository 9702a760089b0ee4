"""Where the samples' rays meet a plane near the initial one, and the shading geometry there.

The plane is parametrised around the initial plane ``(n0, c0)``: the normal is
``normalise(n0 + tilt_1 e1 + tilt_2 e2)`` with ``e1, e2`` orthonormal to ``n0``, the
offset ``c0 + offset_m``. For a sample ray ``X = C + t k`` everything the shading needs
reduces to scalars per sample (``|L - X|^2 = a - 2 t b + t^2 q``, ``n . X = c``), so a
plane hypothesis costs a few vector operations over the samples.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ...geometry import CameraRig, Plane
from ...optics import fresnel_dielectric, ior_from_f0
from .disc import DiscGeometry, disc_geometry, max_disc_rings
from .layout import N_PLANE
from .samples import HighlightSamples

__all__ = ["PlaneReflection"]


@dataclass(frozen=True)
class ShadingGeometry:
    """Shading geometry of the samples for one plane, arrays ``(P,)``.

    Besides the shading terms it keeps the intermediates of their derivatives with
    respect to the plane (see :mod:`~.slopes`).
    """

    cos_h: np.ndarray  # cosine of the half-vector angle
    sin2_h: np.ndarray
    log_foreshortening: np.ndarray  # log(cos_i cos_o)
    diffuse: np.ndarray  # g_d - 1
    specular: np.ndarray  # F / (cos_o r^2), normalised
    normal: np.ndarray  # (3,) unit normal n
    t: np.ndarray  # ray parameter of X = C + t k
    nk: np.ndarray  # n . k
    tq_b: np.ndarray  # t q - b, half the derivative of r^2 along t
    r: np.ndarray  # distance from X to the light
    cos_i: np.ndarray
    cos_o: np.ndarray
    cos_io: np.ndarray  # omega_i . omega_o
    half_norm: np.ndarray  # |omega_i + omega_o|
    grazing: np.ndarray  # 1 - omega_i . h
    fresnel: np.ndarray
    fresnel_slope: np.ndarray  # dF / d(omega_i . h)
    disc: DiscGeometry | None = None  # the light's disc (None: a point light)


class PlaneReflection:
    """The reflection geometry of the samples for planes near an initial plane.

    Parameters
    ----------
    samples : HighlightSamples
        The samples: rays ``k`` and camera centres ``C`` per sample.
    rig : CameraRig
    box : (int, int, int, int)
        ``(x, y, w, h)`` of the object in the reference view; the disparity at its
        corners judges convergence (:meth:`disparity_change_px`).
    light : numpy.ndarray, (3,)
        The light, array frame, metres.
    plane0 : Plane
        The initial plane.
    f0 : float
        Normal-incidence reflectance of the surface.
    fresnel : {"exact", "schlick"}
        The Fresnel equations for the dielectric of that reflectance (refractive index
        ``(1 + sqrt(f0)) / (1 - sqrt(f0))``), or Schlick's approximation of them.
    light_radius_m : float or None
        Radius of the spherical light, metres; None or 0 for a point light. A radius
        gives every geometry the lobe's argument seen through the light's disc
        (:mod:`~.disc`).
    disc_rings : int or None
        Rings of the pattern of points over the disc; None: the most the samples need,
        :data:`~.disc.PIXEL_DISC_RINGS` for samples of one pixel, else
        :data:`~.disc.DISC_RINGS` (a smaller disc needs fewer, :func:`~.disc.disc_rings`).

    Attributes
    ----------
    valid : bool
        Whether the initial plane is valid for every sample (seen from the front, in
        front of the cameras, light in front of it).
    """

    def __init__(self, samples: HighlightSamples, rig: CameraRig, box, light: np.ndarray,
                 plane0: Plane, f0: float, fresnel: str = "exact",
                 light_radius_m: float | None = None, disc_rings: int | None = None) -> None:
        self.f0 = f0
        self.light_radius_m = light_radius_m if light_radius_m else None
        self.disc_rings = disc_rings or max_disc_rings(samples.block_px)
        self.fresnel = fresnel
        self.ior = ior_from_f0(f0)
        self.light = light
        self.n0 = plane0.n
        self.c0 = plane0.offset_m
        helper = np.eye(3)[int(np.argmin(np.abs(self.n0)))]
        e1 = np.cross(self.n0, helper)
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.n0, self.e1)
        # Convergence is judged by the disparity at the corners of the object's box.
        x, y, w, h = box
        corners = np.array([[x, y], [x + w - 1, y], [x, y + h - 1], [x + w - 1, y + h - 1]],
                           dtype=np.float64)
        self.probe_rays = rig.rays(corners)
        self.reference_center_m = rig.reference_center_m
        self.disparity_scale = rig.intrinsics.fx * rig.baseline_m
        # Per-sample constants of the ray-plane algebra (see geometry).
        k, c = samples.ray, samples.camera_m
        self.ray_t = np.ascontiguousarray(k.T)
        self.camera_t = np.ascontiguousarray(c.T)
        self.q = np.einsum("pi,pi->p", k, k)
        self.sqrt_q = np.sqrt(self.q)
        to_light = light - c
        self.a = np.einsum("pi,pi->p", to_light, to_light)
        self.b = np.einsum("pi,pi->p", to_light, k)
        self._cache_key: bytes | None = None
        self._cache: ShadingGeometry | None = None
        # Normalise the geometric factors at the initial plane so the intensities read
        # as luminances at the highlight and the parameters are well scaled.
        self.diffuse_scale = self.spec_scale = 1.0
        geometry = self.geometry(np.zeros(N_PLANE))
        self.valid = geometry is not None
        if not self.valid:
            return
        self.diffuse_scale = 1.0 / float(np.median(geometry.diffuse + 1.0))
        self.spec_scale = 1.0 / float(np.median(geometry.specular))
        # the same geometry with the scales applied is the start's
        diffuse = geometry.diffuse + 1.0
        diffuse *= self.diffuse_scale
        diffuse -= 1.0
        self._cache = dataclasses.replace(geometry, diffuse=diffuse,
                                          specular=geometry.specular * self.spec_scale)
        self._cache_key = np.zeros(N_PLANE).tobytes()

    def planes(self, p: np.ndarray):
        """Return normals ``(B, 3)`` and offsets ``(B,)`` of plane parameters ``(B, 3)``."""
        m = self.n0 + p[:, :1] * self.e1 + p[:, 1:2] * self.e2
        return m / np.linalg.norm(m, axis=1, keepdims=True), self.c0 + p[:, 2]

    def plane(self, theta: np.ndarray) -> Plane:
        """Return the plane of ``theta``'s first three parameters."""
        n, c = self.planes(theta[None, :N_PLANE])
        return Plane(tuple(float(v) + 0.0 for v in n[0]), float(c[0]))

    def geometry(self, plane_params: np.ndarray) -> ShadingGeometry | None:
        """Shading geometry of the samples for plane parameters ``(3,)``.

        Everything reduces to scalars per sample: with ``X = C + t k`` on the plane,
        ``|L - X|^2 = a - 2 t b + t^2 q`` and ``n . X = c``. None if the plane is invalid
        for some sample: seen from behind, behind a camera, or with the light behind it.
        """
        n, c = self.planes(plane_params[None])
        n, c = n[0], float(c[0])
        nk = n @ self.ray_t
        light_height = float(n @ self.light) - c
        if not (nk.max() < 0.0 and light_height > 0.0):
            return None  # some samples see the plane from behind, or the light is behind it
        t = (c - n @ self.camera_t) / nk
        if not t.min() > 0.0:
            return None
        cos_o = np.divide(nk, self.sqrt_q)
        np.negative(cos_o, out=cos_o)
        tq_b = t * self.q
        tq_b -= self.b
        r2 = tq_b - self.b  # |L - X|^2 = t (t q - 2 b) + a
        r2 *= t
        r2 += self.a
        r = np.sqrt(r2)
        cos_i = light_height / r
        cos_io = tq_b / self.sqrt_q  # omega_i . omega_o = (t q - b) / (sqrt(q) r)
        cos_io /= r
        half_norm = cos_io * 2.0  # |omega_i + omega_o|
        half_norm += 2.0
        np.sqrt(half_norm, out=half_norm)
        cos_h = cos_i + cos_o
        cos_h /= half_norm
        np.minimum(cos_h, 1.0, out=cos_h)
        grazing = cos_io + 1.0  # 1 - omega_i . h
        grazing /= half_norm
        np.subtract(1.0, grazing, out=grazing)
        if self.fresnel == "exact":
            fresnel, fresnel_slope = fresnel_dielectric(1.0 - grazing, self.ior, slope=True)
        else:
            # Schlick; powers by multiplication (numpy's ** 5 is a slow generic pow)
            fresnel = grazing * grazing
            fresnel *= fresnel
            # d F / d cos = -5 (1 - f0) x^4 with x = grazing = 1 - cos
            fresnel_slope = fresnel * (-5.0 * (1.0 - self.f0))
            fresnel *= grazing
            fresnel *= 1.0 - self.f0
            fresnel += self.f0
        sin2_h = cos_h * cos_h
        np.subtract(1.0, sin2_h, out=sin2_h)
        log_foreshortening = cos_i * cos_o
        np.log(log_foreshortening, out=log_foreshortening)
        diffuse = cos_i / r2
        diffuse *= self.diffuse_scale
        diffuse -= 1.0
        specular = np.multiply(cos_o, r2, out=r2)
        np.divide(fresnel, specular, out=specular)
        specular *= self.spec_scale
        disc = None
        if self.light_radius_m is not None:
            disc = disc_geometry(cos_h, sin2_h, r, self.light_radius_m, cos_i=cos_i,
                                 cos_o=cos_o, cos_io=cos_io, rings=self.disc_rings)
        return ShadingGeometry(cos_h=cos_h, sin2_h=sin2_h, log_foreshortening=log_foreshortening,
                         diffuse=diffuse, specular=specular, normal=n, t=t, nk=nk, tq_b=tq_b,
                         r=r, cos_i=cos_i, cos_o=cos_o, cos_io=cos_io, half_norm=half_norm,
                         grazing=grazing, fresnel=fresnel,
                         fresnel_slope=fresnel_slope, disc=disc)

    def at(self, theta: np.ndarray) -> ShadingGeometry | None:
        """Geometry of ``theta``'s plane, reused while only the photometry changes."""
        key = theta[:N_PLANE].tobytes()
        if self._cache_key != key:
            self._cache = self.geometry(theta[:N_PLANE])
            self._cache_key = key
        return self._cache

    def directions(self, theta: np.ndarray):
        """Return the derivatives ``(dn (3,), dc)`` of normal and offset by each plane parameter."""
        m = self.n0 + theta[0] * self.e1 + theta[1] * self.e2
        norm = float(np.linalg.norm(m))
        n = m / norm
        # n = m / |m|: dn = (e - n (n . e)) / |m|
        return ((self.e1 - n * float(n @ self.e1)) / norm, 0.0), \
            ((self.e2 - n * float(n @ self.e2)) / norm, 0.0), (np.zeros(3), 1.0)

    def probe_disparity_px(self, thetas: np.ndarray) -> np.ndarray:
        """Return the stereo disparity ``(B, 4)`` at the probe pixels (the box's corners).

        Of the planes of parameter vectors ``thetas`` ``(B, >= N_PLANE)``.
        """
        n, c = self.planes(thetas[:, :N_PLANE])
        # d = fx B / z with 1 / z = (n . k) / (c - n . C_ref) along reference rays k
        return self.disparity_scale * (n @ self.probe_rays.T) / (
            c - n @ self.reference_center_m)[:, None]

    def disparity_change_px(self, before: np.ndarray, after: np.ndarray) -> float:
        """Largest change of the stereo disparity at the probe pixels between two planes."""
        disparity = self.probe_disparity_px(np.stack([before[:N_PLANE], after[:N_PLANE]]))
        return float(np.max(np.abs(disparity[1] - disparity[0])))
