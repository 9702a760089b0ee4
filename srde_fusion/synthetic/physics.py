"""Which physics the renderer simulates: the switches between "the model" and "the world".

The default :class:`Physics` renders what SRDE's photometric refinement assumes
(Schlick's Fresnel, a spherical light folded into a wider lobe, Lambertian diffuse,
Gaussian noise), so fits on such images are exact by construction. A benchmark that
should say how the method does on real glossy objects renders with
:meth:`Physics.faithful`, where every effect is one the refinement does not model:

``fresnel="exact"``
    The Fresnel equations with the material's refractive index (complex for metals)
    instead of Schlick's approximation.
``light="sampled"``
    The spherical light integrated over the disc it presents to each surface point
    (``light_samples`` stratified points) instead of widening the lobe.
``masking="height_correlated"``
    Height-correlated Smith masking-shadowing instead of the separable product.
``diffuse_transmittance=True``
    The diffuse term of a coated material weighted by the light entering and leaving
    the coating, ``(1 - F(cos_l)) (1 - F(cos_v))``.
``full_well_e`` / ``read_noise_e``
    A linear sensor: photon (Poisson) noise on the electrons a pixel collects, plus
    Gaussian read noise, before 8-bit quantisation and clipping.

Pixel-area integration is :func:`~srde_fusion.synthetic.render`'s ``supersample``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SceneError

__all__ = ["FRESNEL_MODELS", "LIGHT_MODELS", "MASKING_MODELS", "Physics"]

FRESNEL_MODELS = ("schlick", "exact")
LIGHT_MODELS = ("widened", "sampled")
MASKING_MODELS = ("separable", "height_correlated")

#: Largest number of light samples per shading point accepted.
MAX_LIGHT_SAMPLES = 1024


@dataclass(frozen=True)
class Physics:
    """Physical effects the renderer simulates (see the module notes).

    Parameters
    ----------
    fresnel : {"schlick", "exact"}
    light : {"widened", "sampled"}
    light_samples : int
        Points on the light's disc per shading point when ``light="sampled"``, a multiple
        of 4 (see :func:`~srde_fusion.synthetic.shading.disc_samples`).
    masking : {"separable", "height_correlated"}
    diffuse_transmittance : bool
    full_well_e : float or None
        Electrons a pixel collects at linear value 1 (the clipping level); None: no photon
        noise. Typical machine-vision sensors hold 5,000-30,000.
    read_noise_e : float
        Standard deviation of the read noise, electrons (needs ``full_well_e``).
    """

    fresnel: str = "schlick"
    light: str = "widened"
    light_samples: int = 64
    masking: str = "separable"
    diffuse_transmittance: bool = False
    full_well_e: float | None = None
    read_noise_e: float = 0.0

    def __post_init__(self) -> None:
        for name, allowed in (("fresnel", FRESNEL_MODELS), ("light", LIGHT_MODELS),
                              ("masking", MASKING_MODELS)):
            if getattr(self, name) not in allowed:
                raise SceneError(f"physics.{name}: expected one of {list(allowed)}, "
                                 f"got {getattr(self, name)!r}")
        n = self.light_samples
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not (
                4 <= n <= MAX_LIGHT_SAMPLES) or n % 4:
            raise SceneError(f"physics.light_samples: expected a multiple of 4 in "
                             f"[4, {MAX_LIGHT_SAMPLES}], got {n!r}")
        if not isinstance(self.diffuse_transmittance, bool):
            raise SceneError(f"physics.diffuse_transmittance: expected a bool, got "
                             f"{self.diffuse_transmittance!r}")
        well = self.full_well_e
        if well is not None and not (isinstance(well, (int, float)) and np.isfinite(well)
                                     and well > 0):
            raise SceneError(f"physics.full_well_e: expected a positive number of electrons "
                             f"or None, got {well!r}")
        read = self.read_noise_e
        if not (isinstance(read, (int, float)) and np.isfinite(read) and read >= 0):
            raise SceneError(f"physics.read_noise_e: expected a non-negative number of "
                             f"electrons, got {read!r}")
        if read > 0 and well is None:
            raise SceneError("physics.read_noise_e: expected full_well_e to be set as well "
                             "(read noise is counted in electrons), got full_well_e=None")

    @classmethod
    def faithful(cls, *, light_samples: int = 64, full_well_e: float = 10_000.0,
                 read_noise_e: float = 5.0) -> Physics:
        """Every effect on: what the refinement's model does not assume."""
        return cls(fresnel="exact", light="sampled", light_samples=light_samples,
                   masking="height_correlated", diffuse_transmittance=True,
                   full_well_e=full_well_e, read_noise_e=read_noise_e)

    def expose(self, linear: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Apply the sensor's photon and read noise to linear values (1 = full well).

        Values stay linear and unclipped above 1 (the encoder clips); without
        ``full_well_e`` the input is returned as it is.
        """
        if self.full_well_e is None:
            return linear
        well = float(self.full_well_e)
        electrons = rng.poisson(np.clip(linear, 0.0, None).astype(np.float64) * well)
        noisy = electrons.astype(np.float32)
        if self.read_noise_e > 0:
            noisy += np.float32(self.read_noise_e) * rng.standard_normal(noisy.shape,
                                                                         dtype=np.float32)
        return noisy * np.float32(1.0 / well)
