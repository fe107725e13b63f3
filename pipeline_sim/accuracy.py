"""Image accuracy: error metrics against converged reference images.

Metrics (:func:`error_metrics`, names in :data:`METRICS`):

* ``rmse``: root mean square error of the *linear* RGB values (the first
  three channels; alpha is ignored), averaged over pixels and channels.
* ``psnr``: ``20 log10(1 / rmse)`` in dB, peak 1.0 on the linear values;
  ``inf`` for identical images.
* ``ssim``: structural similarity (``skimage.metrics.structural_similarity``,
  ``channel_axis=-1``, ``data_range=1.0``, 7x7 window, smaller for images
  under 7 pixels) of the display-encoded images (:func:`to_display`).
* ``flip``: the mean of NVIDIA's LDR FLIP error map (``flip_evaluator``,
  default 67 pixels per degree) of the display-encoded images; 0 is
  identical, 1 is the largest perceived difference. :func:`error_map` returns
  the per-pixel map itself, whose mean is this value.

Display encoding clips the linear RGB to [0, 1] and applies the sRGB
transfer curve (IEC 61966-2-1, as :func:`pipeline_sim.output.linear_to_srgb8`
but kept in float), so ssim and flip judge what the PNG shows, while rmse and
psnr judge the linear values the pipeline resolves.

References (:class:`ReferenceSpec`, :func:`reference_image`):

* ``"pipeline"``: the same simulated pipeline with per-sample shading (one
  shader execution per covered sample, no shading cache) at ``spp`` samples
  per pixel (default 256) of the ``net`` pattern (the t-ordered (0, m, 3)-net,
  not the default ``net5``), with the spec's ``seed`` (independent of the
  scene's own seed). The reference keeps ``net`` on purpose: a construction
  independent of the default pattern's, so a bias of ``net5`` shows in its
  error instead of cancelling against a reference that shares it, and the
  references (and their cache keys) of the runs before ``net5`` became the
  default stay valid. Its own error at 256 spp (about 0.002 RMSE on a
  motion + defocus scene, docs/performance.md) adds in quadrature to a
  measured error and is small beside that of a 16-64 spp image; raise
  ``spp`` or use ``"accumulation"`` for a closer one.
* ``"accumulation"``: the accumulation buffer of Haeberli and Akeley
  (SIGGRAPH 1990): ``passes`` (default 256) single-sample passes, each
  rendering every pixel with ONE point ``(dx, dy, t, u, v)`` (a one-row sample
  table, per-sample shading), averaged. The points are stratified jointly: a
  5D Sobol sequence scrambled with ``seed`` (``scipy.stats.qmc.Sobol``), with
  ``(u, v)`` mapped to the unit disk by the Shirley-Chiu concentric map. Each
  pass uses the same point in every pixel, so its error is correlated across
  the image (structured aliasing rather than noise) and independent of the
  pipeline's per-pixel sample pattern, which makes it a check on that
  pattern too.

Both keep the pass state's settings declared to define the image (depth
test, blending, clip planes, backface culling), take the declared reference
for each accuracy setting (per-sample shading, the net pattern, the
standard rather than conservative mode, the shipped cache geometry) and the
shipped defaults for the rest of the hardware and the simulation options,
which cannot change the image (:func:`pipeline_sim.config.reference_setup`).
So a reference depends only on the scene, its image size, the spec and
those image settings. Both are cached as ``<cache_dir>/<key>.npy`` when a
cache directory is given.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline_sim.config import IMAGE, ArchConfig, reference_setup, settings_of
from pipeline_sim.output import atomic_save_npy
from pipeline_sim.pass_state import PassState
from pipeline_sim.simulation import SimOptions
from pipeline_sim.errors import UserError, did_you_mean

__all__ = ["METRICS", "REFERENCE_KINDS", "ReferenceSpec", "to_display", "error_metrics", "error_map",
           "reference_image"]

#: Metric names returned by :func:`error_metrics`, in this order.
METRICS = ("rmse", "psnr", "ssim", "flip")
#: Reference kinds accepted by :class:`ReferenceSpec`.
REFERENCE_KINDS = ("pipeline", "accumulation")

# Bumped whenever the way a reference is computed changes: old cache files
# then simply stop matching.
_KEY_VERSION = "pipeline-sim-reference-v1"


# ---------------------------------------------------------------------------
# Metrics


def _check_image(name: str, image: np.ndarray) -> np.ndarray:
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise UserError(f"{name}: expected an (H, W, 3) or (H, W, 4) image, got shape {arr.shape}")
    return arr


def _check_pair(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    img = _check_image("image", image)
    ref = _check_image("reference", reference)
    if img.shape[:2] != ref.shape[:2]:
        raise UserError(f"image is {img.shape[1]}x{img.shape[0]} but the reference is "
                        f"{ref.shape[1]}x{ref.shape[0]}")
    return img, ref


def to_display(image: np.ndarray) -> np.ndarray:
    """Linear float (H, W, 3|4) -> sRGB-encoded float32 (H, W, 3) in [0, 1].

    Same transfer curve as :func:`pipeline_sim.output.linear_to_srgb8`
    (NaN -> 0, clipped to [0, 1]), without the 8-bit rounding.
    """
    arr = _check_image("image", image)
    rgb = np.clip(np.nan_to_num(arr[..., :3].astype(np.float64)), 0.0, 1.0)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    return np.clip(srgb, 0.0, 1.0).astype(np.float32)


def _flip(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    import flip_evaluator

    test = np.ascontiguousarray(to_display(image))
    ref = np.ascontiguousarray(to_display(reference))
    fmap, _, _ = flip_evaluator.evaluate(ref, test, "LDR", inputsRGB=True, applyMagma=False,
                                         computeMeanError=False)
    fmap = np.asarray(fmap, dtype=np.float32)
    return fmap.reshape(fmap.shape[0], fmap.shape[1], -1)[..., 0]


def error_map(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-pixel LDR FLIP error (H, W) float32 in [0, 1] of the display-encoded images."""
    img, ref = _check_pair(image, reference)
    return _flip(img, ref)


def _ssim(image: np.ndarray, reference: np.ndarray) -> float:
    from skimage.metrics import structural_similarity

    a, b = to_display(image), to_display(reference)
    if np.array_equal(a, b):
        return 1.0
    side = min(a.shape[0], a.shape[1])
    win = min(7, side if side % 2 else side - 1)
    if win < 3:
        raise UserError(f"ssim needs an image of at least 3x3 pixels, got {a.shape[1]}x{a.shape[0]}")
    return float(structural_similarity(b.astype(np.float64), a.astype(np.float64), channel_axis=-1,
                                       data_range=1.0, win_size=win))


def error_metrics(image: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """rmse, psnr (linear RGB, peak 1.0), ssim and flip (display-encoded) of image vs reference."""
    img, ref = _check_pair(image, reference)
    diff = img[..., :3].astype(np.float64) - ref[..., :3].astype(np.float64)
    rmse = float(np.sqrt(np.mean(diff * diff)))
    psnr = math.inf if rmse == 0.0 else float(-20.0 * math.log10(rmse))
    return {"rmse": rmse, "psnr": psnr, "ssim": _ssim(img, ref), "flip": float(np.mean(_flip(img, ref)))}


# ---------------------------------------------------------------------------
# References


def _canon(obj: Any) -> Any:
    """A JSON-able canonical form (arrays hashed by dtype, shape and bytes)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _canon(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        return {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": hashlib.sha256(a.tobytes()).hexdigest()}
    if isinstance(obj, (list, tuple)):
        return [_canon(x) for x in obj]
    if isinstance(obj, dict):
        return {str(k): _canon(v) for k, v in obj.items()}
    if isinstance(obj, (bool, int, str)) or obj is None:
        return obj
    if isinstance(obj, (float, np.floating)):
        return repr(float(obj))
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot fingerprint {type(obj).__name__}")


def _sha(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _image_settings(arch: ArchConfig, state: PassState) -> dict[str, Any]:
    """The settings declared to define the image (config.IMAGE) that differ from the defaults:
    the reference key includes them, so the keys of default references stay stable."""
    default = settings_of(ArchConfig(), PassState(), SimOptions(), (IMAGE,))
    return {k: v for k, v in settings_of(arch, state, SimOptions(), (IMAGE,)).items() if v != default[k]}


@dataclass(frozen=True)
class ReferenceSpec:
    """How a reference image is made (see the module docstring).

    kind ``"pipeline"``: this pipeline, per-sample shading, ``spp`` samples
    per pixel (the ``net`` pattern, power of two), sample seed ``seed``.
    kind ``"accumulation"``: ``passes`` single-sample passes at jointly
    stratified (scrambled Sobol, seed ``seed``) points, averaged.
    """

    kind: str = "pipeline"
    spp: int = 256
    passes: int = 256
    seed: int = 12345

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> "ReferenceSpec":
        """Raise :class:`UserError` (one line) for an impossible spec."""
        if self.kind not in REFERENCE_KINDS:
            raise UserError(f"reference kind '{self.kind}' is not one of {', '.join(REFERENCE_KINDS)}"
                            f"{did_you_mean(str(self.kind), REFERENCE_KINDS)}")
        for name in ("spp", "passes", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise UserError(f"reference {name} must be an integer, got {v!r}")
        if not 1 <= self.spp <= 1 << 16 or self.spp & (self.spp - 1):
            raise UserError(f"reference spp = {self.spp} must be a power of two from 1 to 65536 "
                            "(the reference's net sample pattern)")
        if self.passes < 1:
            raise UserError(f"reference passes must be >= 1, got {self.passes}")
        if not 0 <= self.seed < 1 << 63:
            raise UserError(f"reference seed must be in 0..2^63-1, got {self.seed}")
        return self

    def key(self, scene, arch: ArchConfig | None = None, state: PassState | None = None) -> str:
        """Stable hex digest naming this reference of ``scene``.

        Covers the scene file digest, the scene's content (camera, light,
        background, objects: :meth:`Scene.replace` keeps the digest), its
        image width and height (not its spp or seed, which the reference
        does not use) and this spec. Only the fields that matter are hashed:
        ``spp`` for ``"pipeline"``, ``passes`` for ``"accumulation"``.
        ``arch`` and ``state`` (default: the scene's pass state) add the
        image-changing settings (back-face culling, depth test, depth write,
        blend, clip planes) that differ from the defaults.
        """
        spec: dict[str, Any] = {"kind": self.kind, "seed": int(self.seed)}
        if self.kind == "pipeline":
            spec["spp"] = int(self.spp)
        else:
            spec["passes"] = int(self.passes)
        content = {name: _canon(getattr(scene, name)) for name in ("camera", "light", "background", "objects")}
        data = {
            "version": _KEY_VERSION,
            "scene_digest": scene.digest,
            "scene_content": _sha(content),
            "image": _sha({"width": int(scene.image.width), "height": int(scene.image.height)}),
            "spec": _sha(spec),
        }
        extra = _image_settings(arch or ArchConfig(), state or scene.pass_state)
        if extra:
            data["arch"] = _sha(_canon(extra))
        return _sha(data)[:32]


def _sobol_table(passes: int, seed: int) -> np.ndarray:
    """(passes, 5) sample-table rows (x, y, u, v, t): scrambled 5D Sobol points
    (dims dx, dy, t, u, v) with (u, v) on the unit disk."""
    from scipy.stats import qmc

    from pipeline_sim.sampling import concentric_disk

    sobol = qmc.Sobol(d=5, scramble=True, seed=seed)
    with warnings.catch_warnings():  # non power-of-two counts lose balance; allowed
        warnings.simplefilter("ignore", UserWarning)
        pts = sobol.random(passes)
    below_one = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
    pts = np.minimum(pts, below_one)
    u, v = concentric_disk(pts[:, 3], pts[:, 4])
    table = np.stack([pts[:, 0], pts[:, 1], np.clip(u, -1.0, 1.0), np.clip(v, -1.0, 1.0), pts[:, 2]], axis=1)
    return table


def _render_reference(scene, spec: ReferenceSpec, arch: ArchConfig, state: PassState,
                      sim: SimOptions) -> np.ndarray:
    from pipeline_sim.render import run_pass, scene_pass

    if spec.kind == "pipeline":
        result = run_pass(scene_pass(scene, arch, spp=spec.spp, seed=spec.seed, sample_table=None,
                                     state=state.replace(sample_pattern="net"), simulation=sim))
        return result.image.astype(np.float32)
    table = _sobol_table(spec.passes, spec.seed)
    base = scene_pass(scene, arch, spp=1, seed=spec.seed, sample_table=table[:1], state=state, simulation=sim)
    acc = np.zeros((scene.image.height, scene.image.width, 4), dtype=np.float64)
    for row in table:
        acc += run_pass(dataclasses.replace(base, sample_table=row[None, :])).image
    return (acc / len(table)).astype(np.float32)


def reference_image(scene, spec: ReferenceSpec = ReferenceSpec(), cache_dir: str | Path | None = None,
                    arch: ArchConfig | None = None) -> np.ndarray:
    """Reference image (H, W, 4) float32 linear RGBA of ``scene`` at its image size.

    ``arch`` defaults to the shipped architecture; the reference keeps the
    image-defining settings of the scene's pass state (depth test, blending,
    clip planes, backface culling) and takes the declared reference for each
    accuracy setting (per-sample shading, the net pattern, standard mode):
    :func:`pipeline_sim.config.reference_setup`. With ``cache_dir`` the
    result is read from / written to ``cache_dir/<spec.key(...)>.npy`` (written
    to a temporary name, then renamed, so readers never see a partial file).
    """
    if not isinstance(spec, ReferenceSpec):
        raise UserError(f"reference spec must be a ReferenceSpec, got {type(spec).__name__}")
    spec.validate()
    ref_arch, ref_state, ref_sim = reference_setup(arch, scene.pass_state)
    shape = (scene.image.height, scene.image.width, 4)
    path = None
    if cache_dir is not None:
        cache = Path(cache_dir)
        path = cache / f"{spec.key(scene, ref_arch, ref_state)}.npy"
        if path.is_file():
            try:
                cached = np.load(path, allow_pickle=False)
            except (OSError, ValueError, EOFError):
                cached = None  # unreadable: recompute and overwrite
            if cached is not None and cached.shape == shape and cached.dtype == np.float32:
                return cached
    image = np.ascontiguousarray(_render_reference(scene, spec, ref_arch, ref_state, ref_sim), dtype=np.float32)
    if path is not None:
        atomic_save_npy(path, image)
    return image
