"""A PSP case whose every input is drawn from its stated distribution: the painted corner
(self-illumination of about 30 % near the edge) seen by one camera, wind-off and wind-on,
for the uncertainty budget's coverage tests.

Truth: a pressure field high on the floor and low on the wall (``p_ref (1 + 0.2 tanh(-s /
0.25))``, ``s`` the signed distance from the corner), a lamp non-uniformity, the
Stern-Volmer law ``I_ref / I = 0.15 + 0.85 p / p_ref``; the radiosity of each image is the
forward solve of the emission with view factors of many rays (``exact_rays``), each image
the per-face radiosity interpolated over the vertices and seen through the **true** pose.

A draw (:meth:`PSPUncertaintyCase.draw`) gives the chain's inputs as a measurement would:

* each pixel: ``I + N(0, I / g + (sigma_r / g)^2)`` (``g`` e-/count, ``sigma_r`` e-);
* the camera's pose: the true pose plus ``theta ~ N(0, Sigma)``, ``Sigma`` the least-squares
  covariance of a resection from the markers with ``marker_px`` per coordinate;
* the form factors: ``rays`` rays a face, a new seed;
* the reflectance: ``rho + u_rho z``;
* the wind-on emission: times ``1 + s dT_i``, ``dT_i ~ N(0, u_T)`` per face, its
  radiosity solved again;
* the taps' pressures: ``+ u_tap z``.

A draw with no source on gives every input at its true value: the chain run on it is the
pressure a measurement without error would give (the reference of the coverage tests; it
differs from the field itself by the chain's discretisation, face mean against face
centre).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from resection.camera.model import Camera

__all__ = ["PSPUncertaintyCase", "psp_uncertainty_case", "write_psp_files", "P_REF",
           "SV", "TUNNEL_PS", "TUNNEL_Q"]

P_REF = 100.0
SV = (0.15, 0.85)
#: The ``.wtd``'s static pressure and dynamic pressure (psf) of :func:`write_psp_files`.
TUNNEL_PS, TUNNEL_Q = 100.0, 40.0


@dataclass
class PSPUncertaintyCase:
    mesh: object
    camera: Camera
    reflectance: float
    p_true: np.ndarray
    b_off: np.ndarray
    b_on: np.ndarray
    tap_ids: list
    tap_points: np.ndarray
    markers: np.ndarray
    level: float
    F: object = None
    e_on: np.ndarray | None = None
    sources: dict = field(default_factory=dict)
    _cache: dict = field(default_factory=dict)

    def images(self, camera=None):
        """Noise-free wind-off and wind-on images through ``camera`` (default: true)."""
        from resection.surface.surface_map import SurfaceMap

        key = id(camera)
        if camera is None or key not in self._cache:
            m = SurfaceMap(self.mesh, camera or self.camera)
            ims = [m.to_image(b * self.level) for b in (self.b_off, self.b_on)]
            if camera is None:
                self._cache[key] = ims
            return ims
        return self._cache[key]

    def draw(self, rng: np.random.Generator, on: set) -> dict:
        """Drawn inputs of one measurement with the sources ``on`` (names as the budget's)."""
        from selfillum.uncertainty.registration import perturbed, pose_covariance

        s = self.sources
        off, onim = self.images()
        cam = self.camera
        if "registration" in on:
            C = pose_covariance(self.camera, self.markers, s["marker"])
            cam = perturbed(self.camera, rng.multivariate_normal(np.zeros(6), C))
        if "noise" in on:
            g, r = s["camera_gain"], s["read_noise"]
            off, onim = (im + np.sqrt(np.maximum(im, 0) / g + (r / g) ** 2)
                         * rng.standard_normal(im.shape) for im in (off, onim))
        rho = self.reflectance
        if "reflectance" in on:
            rho = self.reflectance + s["reflectance"] * rng.standard_normal()
        if "temperature" in on:  # each face's paint a little warmer or cooler wind-on
            from resection.surface.surface_map import SurfaceMap
            from selfillum.solve.radiosity import forward

            fac = 1.0 + s["paint_temperature"] * s["temperature"] * \
                rng.standard_normal(len(self.mesh.faces))
            b_on = forward(self.F, self.e_on * fac, self.reflectance)
            # the change per face, uniform on each face (an image interpolated over the
            # vertices would average neighbouring faces' independent changes)
            onim = self.images()[1] + SurfaceMap(self.mesh, self.camera).to_image(
                (b_on - self.b_on) * self.level, interpolation="nearest")
            if "noise" in on:
                g, r = s["camera_gain"], s["read_noise"]
                onim = onim + np.sqrt(np.maximum(onim, 0) / g + (r / g) ** 2) \
                    * rng.standard_normal(onim.shape)
        taps = self.p_true_taps.copy()
        if "calibration" in on:
            taps = taps + s["taps"] * rng.standard_normal(taps.shape)
        return {"camera": cam, "off": off, "on": onim, "reflectance": rho, "taps": taps,
                "rays_seed": int(rng.integers(1, 2**31)) if "si_rays" in on else None}

    @property
    def p_true_taps(self) -> np.ndarray:
        from selfillum.images.psp import tap_faces

        return self.p_true[tap_faces(self.mesh, self.tap_points)]


def psp_uncertainty_case(*, resolution: int = 10, exact_rays: int = 8192,
                         width: int = 240, height: int = 180, level: float = 2000.0,
                         **sources) -> PSPUncertaintyCase:
    """The case; ``sources`` override the stated uncertainties (``camera_gain`` e-/count,
    ``read_noise`` e-, ``marker`` px, ``reflectance``, ``paint_temperature`` 1/K,
    ``temperature`` K, ``taps`` in the pressure's unit)."""
    from scenes.corner import corner
    from selfillum.solve.radiosity import forward
    from selfillum.transport.viewfactors import view_factors

    sc = corner(resolution=resolution, reflectance=0.6, pattern="uniform")
    mesh = sc.mesh
    c = np.asarray(mesh.triangles_center)
    sdist = np.where(sc.plate == 0, -c[:, 0], c[:, 2])
    p_true = P_REF * (1.0 + 0.2 * np.tanh(-sdist / 0.25))
    excitation = 1.0 + 0.3 * c.sum(axis=1)
    A, B = SV
    e_off = excitation / (A + B)
    e_on = excitation / (A + B * p_true / P_REF)
    F = view_factors(mesh, rays_per_face=exact_rays, seed=12345)
    b_off = forward(F, e_off, sc.reflectance)
    b_on = forward(F, e_on, sc.reflectance)
    f = 260.0 * width / 320.0
    # a little roll and offset: no edge of the grid along a pixel column (a real camera)
    cam = Camera.look_at([1.4, 0.47, 1.2], [0.3, 0.52, 0.3], [0.07, 1, 0.02],
                         K=[[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]],
                         width=width, height=height)
    rng = np.random.default_rng(7)
    far = np.flatnonzero(np.abs(sdist) > 0.3)
    pick = np.concatenate([rng.choice(far[sc.plate[far] == k], 8, replace=False)
                           for k in (0, 1)])
    u = np.linspace(0.1, 0.9, 4)
    U, V = np.meshgrid(u, u)
    floor = np.column_stack([U.ravel(), V.ravel(), np.zeros(U.size)])
    wall = np.column_stack([np.zeros(U.size), V.ravel(), U.ravel()])
    stated = {"camera_gain": 4.0, "read_noise": 10.0, "marker": 0.05, "reflectance": 0.02,
              "paint_temperature": 0.01, "temperature": 0.3, "taps": 0.1}
    stated.update(sources)
    return PSPUncertaintyCase(mesh, cam, sc.reflectance, p_true, b_off, b_on,
                              [f"T{i}" for i in range(pick.size)], c[pick],
                              np.vstack([floor, wall]), level, F, e_on, stated)


def write_psp_files(case: PSPUncertaintyCase, folder, frames: int, *, rays: int = 256,
                    seed: int = 4) -> list:
    """The case as ``selfillum psp`` reads it, in ``folder``: the mesh (``corner.ply``), the
    camera (``cam.json``), wind-off / wind-on NPY stacks of ``frames`` frames with the
    camera's noise drawn (one image for ``frames`` 1), the taps as Cp in a ``.wtd``
    (``PS`` :data:`TUNNEL_PS`, ``Q`` :data:`TUNNEL_Q`) placed by a ``.tgts`` whose targets
    are the markers. Returns the command's arguments (without ``--uncertainty`` nor
    ``--out``), ``rays`` rays a face."""
    from pathlib import Path

    from resection.io.cameras import write_camera

    folder = Path(folder)
    rng = np.random.default_rng(seed)
    g, r = case.sources["camera_gain"], case.sources["read_noise"]
    off, on = case.images()
    case.mesh.export(folder / "corner.ply")
    write_camera(folder / "cam.json", case.camera)
    for name, im in (("off", off), ("on", on)):
        st = im[None] + np.sqrt(np.maximum(im, 0) / g + (r / g) ** 2)[None] \
            * rng.standard_normal((frames,) + im.shape)
        np.save(folder / f"{name}.npy", (st if frames > 1 else st[0]).astype(np.float32))
    ps, q = TUNNEL_PS, TUNNEL_Q
    cp = (case.p_true_taps - ps) / q
    (folder / "run.wtd").write_text(
        f"# MACH\tALPHA\tTTF\tPS\tQ\n0.5\t0.0\t80.0\t{ps!r}\t{q!r}\n# Tap CP\n"
        + "".join(f"{k + 1}\t{float(v)!r}\n" for k, v in enumerate(cp)))
    rows = ["*Targets"] + [f"{k + 1} {x!r} {y!r} {z!r} 0 0 1 0.01 1 1 1 M{k + 1}"
                           for k, (x, y, z) in enumerate(case.markers.tolist())] + ["*Taps"]
    rows += [f"{k + 100} {x!r} {y!r} {z!r} 0 0 1 0.005 1 1 1 CP{k + 1:02d}"
             for k, (x, y, z) in enumerate(case.tap_points.tolist())]
    (folder / "model.tgts").write_text("\n".join(rows) + "\n")
    return ["psp", "--mesh", str(folder / "corner.ply"), "--camera", str(folder / "cam.json"),
            "--wind-off", str(folder / "off.npy"), "--wind-on", str(folder / "on.npy"),
            "--taps", str(folder / "run.wtd"), "--tap-positions", str(folder / "model.tgts"),
            "--p-ref", repr(P_REF), "--reflectance", str(case.reflectance), "--rays",
            str(rays), "--quiet"]
