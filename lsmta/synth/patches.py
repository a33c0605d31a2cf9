"""Image pairs with a known affine and radiometric warp, for measuring image matching.

The texture is a sum of random 2-D sinusoids (band-limited, wavelengths in a chosen band)
evaluated analytically, so no interpolator is involved in making the data. Each pixel is
the mean over an ``s x s`` grid of points inside it (``s = 4``: "rendered at 4x resolution
and averaged down"). The search image shows the same texture through a known warp::

    template(u) = r0 + r1 * search(c + A u)      for template pixel coordinates u,

i.e. a template point ``u`` appears at ``c + A u`` in the search image (``c`` here is the
image of the template's origin). Noise is added to both images independently, then both
are rounded to 8 bits; :meth:`WarpedPair.noisy` draws fresh noise for the same clean pair
(cheap, for noise sweeps). Values and gradients of the noise-free images are available
anywhere, for Cramér-Rao bounds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_array, as_rng, as_scalar


@dataclass(frozen=True, eq=False)
class PlanarTexture:
    """``t(x, y) = mean + amplitude * sqrt(2/n) * sum_k sin(2 pi (d_k . x) / l_k + phi_k)``.

    Build with :meth:`random`. ``amplitude`` is the standard deviation in grey levels.
    """

    directions: np.ndarray
    wavelengths: np.ndarray
    phases: np.ndarray
    mean: float
    amplitude: float

    @classmethod
    def random(cls, *, rng: np.random.Generator | int | None = None, amplitude: float = 30.0,
               mean: float = 128.0, wavelength=(4.0, 24.0), n_waves: int = 40) -> PlanarTexture:
        """Random directions, log-uniform wavelengths (pixels) and phases."""
        rng = as_rng(rng)
        lo, hi = (as_scalar(w, "wavelength", positive=True) for w in wavelength)
        d = rng.normal(size=(n_waves, 2))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        lam = np.exp(rng.uniform(np.log(lo), np.log(hi), n_waves))
        phi = rng.uniform(0, 2 * np.pi, n_waves)
        return cls(d, lam, phi, float(mean), as_scalar(amplitude, "amplitude", nonnegative=True))

    def __call__(self, x, y, gradient: bool = False):
        """Values (and d/dx, d/dy) at points ``x, y`` of any matching shape."""
        k = 2 * np.pi / self.wavelengths
        amp = self.amplitude * np.sqrt(2.0 / len(k))
        value = np.full(np.shape(x), self.mean, dtype=float)
        gx = np.zeros(np.shape(x))
        gy = np.zeros(np.shape(x))
        for j in range(len(k)):
            arg = k[j] * (self.directions[j, 0] * x + self.directions[j, 1] * y) + self.phases[j]
            value += amp * np.sin(arg)
            if gradient:
                cos = amp * k[j] * np.cos(arg)
                gx += cos * self.directions[j, 0]
                gy += cos * self.directions[j, 1]
        return (value, gx, gy) if gradient else value


@dataclass(frozen=True, eq=False)
class WarpedPair:
    """A template and a search image related by a known warp (see the module docstring).

    Attributes
    ----------
    template, search : (H, W) arrays
        The images handed to a matcher (uint8 unless ``quantise=False``).
    clean_template, clean_search_image : (H, W) float arrays
        The same before noise and rounding.
    A : (2, 2) array
    c : (2,) array
        Search position of template pixel (0, 0).
    r0, r1 : float
        Radiometric offset and gain.
    noise_sigma : float
    texture : PlanarTexture
    supersample : int
    """

    template: np.ndarray
    search: np.ndarray
    clean_template: np.ndarray
    clean_search_image: np.ndarray
    A: np.ndarray
    c: np.ndarray
    r0: float
    r1: float
    noise_sigma: float
    texture: PlanarTexture
    supersample: int

    def noisy(self, noise_sigma: float, *, rng: np.random.Generator | int | None = None,
              quantise: bool = True) -> WarpedPair:
        """The same pair with fresh Gaussian noise in both images (and 8-bit rounding)."""
        rng = as_rng(rng)
        sigma = as_scalar(noise_sigma, "noise_sigma", nonnegative=True)
        images = []
        for img in (self.clean_template, self.clean_search_image):
            img = img + rng.normal(0.0, sigma, img.shape) if sigma > 0 else img
            images.append(np.clip(np.rint(img), 0, 255).astype(np.uint8) if quantise else img)
        return replace(self, template=images[0], search=images[1], noise_sigma=sigma)

    def with_amplitude(self, amplitude: float) -> WarpedPair:
        """The same pair with the texture's contrast scaled to ``amplitude`` (noise-free)."""
        k = as_scalar(amplitude, "amplitude", nonnegative=True) / self.texture.amplitude
        m = self.texture.mean
        tex = replace(self.texture, amplitude=self.texture.amplitude * k)
        ms = (m - self.r0) / self.r1            # the texture mean seen in the search image
        return replace(self, texture=tex, noise_sigma=0.0,
                       template=m + k * (self.clean_template - m),
                       search=ms + k * (self.clean_search_image - ms),
                       clean_template=m + k * (self.clean_template - m),
                       clean_search_image=ms + k * (self.clean_search_image - ms))

    def true_xy(self, template_xy) -> np.ndarray:
        """Where template points ``(N, 2)`` appear in the search image: ``c + A u``."""
        u = as_array(template_xy, "template_xy", shape=(None, 2))
        return self.c + u @ self.A.T

    def clean_search(self, xy, *, gradient: bool = False):
        """The noise-free search image as a continuous function of ``xy`` ``(..., 2)``.

        It is the pixel average of the warped texture, so at pixel centres it equals the
        search image before noise and rounding.
        """
        xy = np.asarray(xy, float)
        Ainv = np.linalg.inv(self.A)
        s = self.supersample
        offs = (np.arange(s) + 0.5) / s - 0.5
        value = np.zeros(xy.shape[:-1])
        gx = np.zeros(xy.shape[:-1])
        gy = np.zeros(xy.shape[:-1])
        for oy in offs:
            for ox in offs:
                p = (xy + (ox, oy) - self.c) @ Ainv.T
                out = self.texture(p[..., 0], p[..., 1], gradient)
                if gradient:
                    v, tx, ty = out
                    gx += tx * Ainv[0, 0] + ty * Ainv[1, 0]     # chain rule through A^-1
                    gy += tx * Ainv[0, 1] + ty * Ainv[1, 1]
                else:
                    v = out
                value += v
        n = s * s
        value = (value / n - self.r0) / self.r1
        if gradient:
            return value, gx / n / self.r1, gy / n / self.r1
        return value


def _render(fn, shape, s):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    offs = (np.arange(s) + 0.5) / s - 0.5
    acc = np.zeros(shape)
    for oy in offs:
        for ox in offs:
            acc += fn(xx + ox, yy + oy)
    return acc / (s * s)


def warped_pair(*, shape=(256, 256), rng: np.random.Generator | int | None = None,
                A=((1.0, 0.0), (0.0, 1.0)), c=(0.0, 0.0), r0: float = 0.0, r1: float = 1.0,
                noise_sigma: float = 0.0, amplitude: float = 30.0, wavelength=(4.0, 24.0),
                supersample: int = 4, quantise: bool = True,
                texture: PlanarTexture | None = None) -> WarpedPair:
    """Make a template and a search image of one random texture under a known warp.

    Parameters
    ----------
    rng : numpy.random.Generator, int or None
        Draws the texture (unless given) and the noise.
    shape : (int, int)
        Image size (H, W), both images.
    A : (2, 2) array
        Geometric warp (template -> search).
    c : (2,) array
        Search position of template pixel (0, 0), pixels.
    r0, r1 : float
        ``template = r0 + r1 * search``.
    noise_sigma : float
        Gaussian noise added to each image, grey levels.
    amplitude : float
        Texture standard deviation (texture strength), grey levels.
    wavelength : (float, float)
        Texture wavelength band, pixels (template frame).
    supersample : int
        Points per pixel along each axis for the pixel average.
    quantise : bool
        Round to uint8 (clipping to 0..255).
    """
    rng = as_rng(rng)
    A = as_array(A, "A", shape=(2, 2))
    if np.linalg.det(A) <= 0:
        raise ValueError("A: expected an orientation-preserving warp (det(A) > 0)")
    c = as_array(c, "c", shape=(2,))
    r1 = as_scalar(r1, "r1", positive=True)
    noise_sigma = as_scalar(noise_sigma, "noise_sigma", nonnegative=True)
    tex = texture if texture is not None else PlanarTexture.random(rng=rng, amplitude=amplitude,
                                                                   wavelength=wavelength)
    pair = WarpedPair(template=np.empty(0), search=np.empty(0), clean_template=np.empty(0),
                      clean_search_image=np.empty(0), A=A, c=c, r0=float(r0), r1=r1,
                      noise_sigma=0.0, texture=tex, supersample=int(supersample))
    template = _render(lambda x, y: tex(x, y), shape, pair.supersample)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    search = pair.clean_search(np.stack([xx, yy], axis=-1))
    pair = replace(pair, clean_template=template, clean_search_image=search)
    return pair.noisy(noise_sigma, rng=rng, quantise=quantise)
