"""Simulate one trigger of the rig: a (defective) part, in a random pose, rendered by every camera."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from inspector.errors import RecipeError, ReferenceMeshError
from inspector.model import Capture, Rig, Truth
from inspector.params import param

if TYPE_CHECKING:
    from inspector_drivers.sim.optics import Optics

__all__ = ["SimParams", "simulate", "sim_rig", "random_pose"]


@dataclass(frozen=True)
class SimParams:
    """Parameters of the simulated rig and part (also the ``sim`` driver's parameters)."""

    part: str = param("cube30", "built-in part name (see `inspector plugins`) or a mesh file (STL/PLY/OBJ, mm) as the true part")
    count: int = param(1, "captures to acquire", min=1)
    seed: int = param(0, "random seed: pose, offset, defects and noise of capture i use seed + i", min=0, max=2**31 - 1)
    scale: float = param(1.0, "scale of the true part about its centre (1.0: as the reference)", min=0.5, max=2.0)
    bumps: tuple[dict, ...] = param((), "explicit bumps: tables {at = [x, y, z], radius_mm = r, kind = 'add'|'remove'} in the part's frame")
    random_bumps: int = param(0, "number of random bumps on the surface", min=0, max=1000)
    defect_every: int = param(0, "only every Nth capture (the Nth, 2Nth, ...) gets the bumps, a good part in between (0: every capture)", min=0)
    bump_radius_mm: float = param(3.0, "largest random bump radius, mm", min=0.1, max=10.0)
    bump_kind: Literal["add", "remove", "any"] = param("any", "kind of the random bumps")
    pose: Literal["random", "identity"] = param("random", "orientation of the part (a falling part is never upright)")
    offset_mm: float = param(5.0, "largest random offset of the part from the rig centre, mm", min=0.0, max=1000.0)
    noise_sigma: float = param(2.0, "Gaussian image noise, grey levels (8-bit scale)", min=0.0, max=255.0)
    impulse_fraction: float = param(0.0, "fraction of pixels hit by salt-and-pepper noise", min=0.0, max=0.5)
    binary: bool = param(False, "hard-edged images (no anti-aliasing)")
    bit_depth: Literal[8, 16] = param(8, "image bit depth")
    supersample: int = param(8, "sub-samples per pixel side on the silhouette edges", min=1, max=32)
    cameras: int = param(16, "cameras spread over the sphere (no two opposite)", min=3, max=64)
    radius_mm: float = param(400.0, "distance of the cameras to the rig centre, mm", min=10.0, max=10000.0)
    mm_per_px: float = param(0.1, "pixel footprint at the rig centre, mm", min=0.001, max=100.0)
    width: int = param(1024, "image width, px", min=16, max=16384)
    height: int = param(1024, "image height, px", min=16, max=16384)
    dist: tuple[float, ...] = param((), "lens distortion [k1, k2, p1, p2, k3] of every camera (empty: none)")
    background: float = param(200.0, "background grey level (8-bit scale)", min=0.0, max=255.0)
    foreground: float = param(40.0, "object grey level (8-bit scale)", min=0.0, max=255.0)
    # Real optics (issue 26; inspector_drivers/sim/optics.py): applied to the noise-free image, before the noise.
    vignetting: float = param(1.0, "background level at the image corners relative to the centre (1: none; 0.6: 60 percent)", min=0.05, max=1.0)
    vignetting_model: Literal["cos4", "poly"] = param("cos4", "vignetting law: cos^4 of the field angle, or 1 - a r^2")
    dust: int = param(0, "dark specks per camera, in the same places in every capture and in the background images", min=0, max=100000)
    dust_max_px: float = param(4.0, "largest speck diameter, px (the smallest: 1 px)", min=1.0, max=100.0)
    dust_depth: float = param(0.8, "largest fraction of the light a speck takes (the smallest: 0.3, or this if less)", min=0.01, max=1.0)
    dust_seed: int = param(0, "seed of the specks' places, with the camera's index (not the capture's)", min=0, max=2**31 - 1)
    bloom_fraction: float = param(0.0, "blooming: fraction of the light spread in a halo around bright areas", min=0.0, max=0.9)
    bloom_radius_px: float = param(6.0, "blooming: radius of the halo, px", min=0.5, max=200.0)
    defocus_px: float = param(0.0, "defocus: Gaussian blur sigma, px", min=0.0, max=50.0)
    motion_blur_px: float = param(0.0, "motion blur: how far the part moves in the image during the exposure, px", min=0.0, max=200.0)
    motion_deg: float = param(0.0, "motion blur direction, degrees from the image's u axis towards v", min=-360.0, max=360.0)
    background_frames: int = param(
        0, "also write each camera's empty-field image (background/<cam>.png), this many frames averaged (0: none)", min=0, max=10000
    )

    def __post_init__(self) -> None:
        for i, b in enumerate(self.bumps):
            if set(b) - {"at", "radius_mm", "kind"} or "at" not in b or "radius_mm" not in b:
                raise ValueError(f"bumps[{i}]: expected {{at = [x, y, z], radius_mm = r, kind = 'add'|'remove'}}")
            at = b["at"]
            if not (isinstance(at, (list, tuple)) and len(at) == 3 and all(isinstance(x, (int, float)) for x in at)):
                raise ValueError(f"bumps[{i}].at: expected 3 numbers")
            if not isinstance(b["radius_mm"], (int, float)) or b["radius_mm"] <= 0:
                raise ValueError(f"bumps[{i}].radius_mm: expected a positive number")
            if b.get("kind", "remove") not in ("add", "remove"):
                raise ValueError(f"bumps[{i}].kind: expected 'add' or 'remove'")
        if self.dist and len(self.dist) not in (4, 5):
            raise ValueError("dist: expected 4 or 5 coefficients")
        if (self.optics.active or self.background_frames) and self.foreground == self.background:
            raise ValueError("optics effects and background images need a contrast: foreground and background levels are equal")

    @property
    def optics(self) -> Optics:
        """The optics effects of these parameters (:class:`~inspector_drivers.sim.optics.Optics`)."""
        from inspector_drivers.sim.optics import Optics

        return Optics(
            vignetting=self.vignetting,
            vignetting_model=self.vignetting_model,
            dust=self.dust,
            dust_size_px=(1.0, max(self.dust_max_px, 1.0)),
            dust_depth=(min(0.3, self.dust_depth), self.dust_depth),
            dust_seed=self.dust_seed,
            bloom_fraction=self.bloom_fraction,
            bloom_radius_px=self.bloom_radius_px,
            defocus_px=self.defocus_px,
            motion_px=self.motion_blur_px,
            motion_deg=self.motion_deg,
        )


def sim_rig(p: SimParams) -> Rig:
    """The simulated rig of these parameters."""
    from inspector_drivers.sim.rig import sphere_rig

    return sphere_rig(
        p.cameras,
        radius_mm=p.radius_mm,
        width=p.width,
        height=p.height,
        mm_per_px=p.mm_per_px,
        dist=list(p.dist) if p.dist else None,
    )


def random_pose(rng: np.random.Generator, offset_mm: float, random_rotation: bool = True) -> np.ndarray:
    """A 4x4 part -> world transform: uniform random rotation, offset uniform in a ball."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    if random_rotation:
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    T[:3, 3] = d * offset_mm * rng.uniform() ** (1 / 3)
    return T


def _true_part(p: SimParams, rng: np.random.Generator, index: int = 0) -> tuple[Any, list[dict[str, Any]]]:
    from inspector.parts import Bump, apply_defects, load_reference, part_names, random_bumps

    spec = p.part if (p.part.startswith("builtin:") or "." in p.part or "/" in p.part) else f"builtin:{p.part}"
    if spec.startswith("builtin:") and spec[8:] not in part_names():
        raise RecipeError(f"sim: unknown part {p.part!r} (known: {', '.join(part_names())})")
    try:
        mesh = load_reference(spec)
    except ReferenceMeshError as e:
        raise RecipeError(f"sim: part: {e}") from None
    bumps = [Bump(tuple(b["at"]), float(b["radius_mm"]), b.get("kind", "remove")) for b in p.bumps]
    if p.defect_every and (index + 1) % p.defect_every:
        bumps = []  # a good part between two defective ones
    elif p.random_bumps:
        kind = None if p.bump_kind == "any" else p.bump_kind
        bumps += list(
            random_bumps(mesh, p.random_bumps, max_radius_mm=p.bump_radius_mm, min_radius_mm=min(0.5, p.bump_radius_mm), kind=kind, rng=rng)
        )
    true = apply_defects(mesh, scale=p.scale, bumps=bumps)
    return true, [{"at": list(b.centre), "radius_mm": b.radius_mm, "kind": b.kind} for b in bumps]


def _levels_to_coverage(grey: np.ndarray, p: SimParams) -> np.ndarray:
    """Grey levels (8-bit scale) -> the "coverage" that :func:`to_image` turns back into them
    (outside [0, 1] where the optics made a level beyond the object's or the background's)."""
    return ((grey - np.float32(p.background)) / np.float32(p.foreground - p.background)).astype(np.float32)


def _through_optics(cov: np.ndarray, p: SimParams, optics: Optics, camera_index: int) -> tuple[np.ndarray, np.ndarray]:
    """Coverage (H, W) -> the coverage whose image is the noise-free image through ``optics``,
    and the camera's vignetting x dust gain (H, W) float32 (reused for its background image)."""
    from inspector_drivers.sim.optics import apply_optics, field_gain

    height, width = cov.shape
    gain = field_gain(optics, height, width, camera_index)
    grey = np.float32(p.background) + np.float32(p.foreground - p.background) * np.asarray(cov, np.float32)
    return _levels_to_coverage(apply_optics(grey, optics, camera_index, gain), p), gain


def simulate(p: SimParams, index: int = 0, rig: Rig | None = None, *, name: str | None = None) -> Capture:
    """Render capture number ``index`` of these parameters.

    Returns
    -------
    Capture
        Images of every camera, polarity ``dark-object`` (or bright when the levels say
        so), and a :class:`~inspector.model.Truth` holding the true surface in world mm,
        the true pose (part -> world) and the defects.
    """
    from inspector_drivers.sim.render import render_coverage, to_image

    rig = rig if rig is not None else sim_rig(p)
    rng = np.random.default_rng(p.seed + index)
    true, bumps = _true_part(p, rng, index)
    pose = random_pose(rng, p.offset_mm, p.pose == "random")
    world = true.copy()
    world.apply_transform(pose)
    cover = render_coverage(world, rig, supersample=1 if p.binary else p.supersample)
    optics = p.optics
    gains = {}
    images = {}
    for k, cam in enumerate(rig.cameras):
        c = cover[cam.name]
        if p.binary:
            c = (c >= 0.5).astype(np.float32)
        if optics.active:
            c, gains[cam.name] = _through_optics(c, p, optics, k)
        images[cam.name] = to_image(
            c,
            rng=rng,
            background=p.background,
            foreground=p.foreground,
            noise_sigma=p.noise_sigma,
            impulse_fraction=p.impulse_fraction,
            bit_depth=p.bit_depth,
        )
    backgrounds = {}
    if p.background_frames > 0:
        from inspector_drivers.sim.optics import empty_field, field_gain

        # Drawn after the images, so these do not depend on background_frames.
        for k, cam in enumerate(rig.cameras):
            h, w = int(cam.height), int(cam.width)
            g = gains.get(cam.name)
            field = empty_field(p.background, optics, h, w, k, g if g is not None else field_gain(optics, h, w, k))
            backgrounds[cam.name] = to_image(
                _levels_to_coverage(field, p),
                rng=rng,
                background=p.background,
                foreground=p.foreground,
                noise_sigma=p.noise_sigma / float(np.sqrt(p.background_frames)),
                bit_depth=p.bit_depth,
            )
    polarity = "dark-object" if p.foreground < p.background else "bright-object"
    info = {
        "part": p.part,
        "scale": p.scale,
        "bumps": bumps,
        "pose": pose.tolist(),
        "noise_sigma": p.noise_sigma,
        "impulse_fraction": p.impulse_fraction,
        "binary": p.binary,
        "seed": p.seed + index,
        "mm_per_px": p.mm_per_px,
    }
    if optics.active:
        info["optics"] = {k: v for k, v in dataclasses.asdict(optics).items()}
    cap_name = name or f"{p.part.replace('/', '_')}-s{p.seed + index:04d}"
    return Capture(
        name=cap_name,
        rig=rig,
        images=images,
        backgrounds=backgrounds,
        polarity=polarity,
        metadata={"part_id": cap_name, "simulated": True},
        truth=Truth(None, info, np.asarray(world.vertices, float), np.asarray(world.faces, np.int64)),
    )
