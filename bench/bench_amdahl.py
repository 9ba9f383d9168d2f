"""Serial share (Amdahl) of the whole ``selfillum correct`` command, per part, and the
thread efficiency of ``view_factors`` (issue 21 item 5).

Run: ``.venv/bin/python bench/bench_amdahl.py [--faces 609000] [--repeat 2]
[--threads 1,2,4,8,16] [--roots A,B] [--track-frames 2,2000 [--skip-correct]]``

**track.** With ``--track-frames`` the ``resection track`` command of
``bench_track_command.py`` (body of revolution) runs for each number of frames: wall and
CPU seconds of the whole process; CPU over wall says how many cores it kept busy.

**Parts.** The command runs in a fresh process (this script with ``--child``) that times,
by wrapping the library's functions (no change to the library), the wall and process CPU
seconds of: the imports (every module the command loads before its work, imported up
front; what it imports on a thread while its rays run, SciPy's sparse solvers and the
solve, is imported there, inside "ray tracing"), reading the
grid, the camera and the image, building the ``SurfaceMap``, the camera check, the Embree
scene and kernels of the view factors, the ray tracing (worker threads), the assembly of
``F`` from the traced rows, the solve (``selfillum.correct``, the continuation's CG
inside), the per-pixel correction (``SurfaceMap.to_image``) and writing. What no wrapper
covers (argument checks, ``to_surface``, the painted-side check, ...) is "other".

A part is *parallel* when its code runs on several threads (the ray tracing, the
SurfaceMap's Embree queries, which are inside "SurfaceMap", the Embree scene, whose BVH
Embree builds on its own threads); every other part runs on one thread and is *serial*.
The serial share is serial wall seconds over the command's wall seconds (the
interpreter's start included, timed by the parent). ``cpu/wall`` of each part
is printed as a check: about 1 for a serial part, up to 2 for a parallel one on 2 free
cores (less when other processes take the cores).

With ``--roots`` the command of each source tree (``PYTHONPATH``) runs in turn, interleaved
round by round, e.g. the previous commit unpacked with ``git archive`` against this one.

**Floor.** Before the parts, the wall seconds of a process that makes one cached compiled
call of the package and nothing else (``FLOOR``), of the same with a one-line kernel of a
module of its own, without the package (``BARE_FLOOR``), and of an empty interpreter: no
command that runs compiled code has a serial share below its floor's share of its time.

**Threads.** ``view_factors`` of the same grid (every row, K = 256, or ``--vf-faces``
rows) with ``workers`` = each of ``--threads``, interleaved, best of ``--repeat``. The
efficiency from 2 to ``w`` threads is ``T(2) * 2 / (T(w) * min(w, cores))``; with more
threads than cores it only shows the cost of the extra threads (chunking, pool, the serial
start and assembly), not the speed-up more cores would give: for that, the serial share
of ``view_factors`` measured here gives Amdahl's bound ``1 / (s + (1 - s) / (w / 2))``
at ``w`` cores from 2.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

T_START = time.perf_counter()
#: The caller's NUMBA_NUM_THREADS: the commands run with it (the thread bench raises the
#: cap of this process to its largest thread count).
_NUMBA_THREADS = os.environ.get("NUMBA_NUM_THREADS")

ROOT = Path(__file__).resolve().parents[1]

#: (label, module, attribute path, parallel?) of the functions timed in the child.
PARTS = [
    ("grid reading", "resection.io.meshes", "load_mesh", False),
    ("grid reading", "resection.io.meshes", "read_surface", False),
    ("camera reading", "resection.io.cameras", "read_camera_file", False),
    ("image reading", "resection.io.images", "read_native", False),
    # the BVH build runs on Embree's own threads (cpu/wall 1.8-1.95 on 2 free cores)
    ("Embree scene", "resection.surface.visibility", "RayCaster.__init__", True),
    ("Embree scene", "selfillum.transport.viewfactors", "RayScene.__init__", True),
    ("SurfaceMap", "resection.surface.surface_map", "SurfaceMap.__init__", False),
    ("SurfaceMap rays", "resection.surface.visibility", "RayCaster.first_hit", True),
    ("SurfaceMap rays", "resection.camera.model", "Camera.undistortion_map", True),
    ("camera check", "resection.pose.camera_fit", "check_camera", False),
    ("scene + kernels", "selfillum.transport.viewfactors", "RowTracer._start", False),
    ("ray tracing", "selfillum.transport.viewfactors", "RowTracer.rows", True),
    ("ray tracing", "selfillum.transport.viewfactors", "RowTracer.hits", True),
    ("F assembly", "selfillum.transport.viewfactors", "_assemble", False),
    ("F assembly (threads)", "selfillum.transport.rowtrace", "_sort_rows", True),
    ("F assembly (threads)", "selfillum.transport.rowtrace", "_fill_rows", True),
    ("solve (CG)", "selfillum.solve.radiosity", "correct", False),
    ("to_surface", "resection.surface.surface_map", "SurfaceMap.to_surface", False),
    ("to_image", "resection.surface.surface_map", "SurfaceMap.to_image", False),
    ("checks", "selfillum.mesh", "check_mesh", False),
    ("checks", "selfillum.images.image_correction", "_check_painted_side", False),
    ("F bookkeeping", "selfillum.images.image_correction", "coupled_view_factors", False),
    ("summary", "selfillum.summary", "summarize", False),
    ("writing", "selfillum.summary", "write_summary", False),
    ("writing", "numpy", "save", False),
]
#: Imported up front (their time is "imports"); trimesh is not: a tree whose command needs it
#: imports it through these modules or later, inside the part that needs it.
IMPORTS = ["numpy", "numba", "embreex",
           "selfillum.images.image_correction", "selfillum.summary", "resection.saturation",
           "resection.io.cameras", "resection.io.meshes", "resection.io.markers",
           "resection.io.marks", "resection.io.outputs", "resection.pose.camera_fit",
           "resection.surface.surface_map", "selfillum.transport.viewfactors",
           "selfillum.transport.coupling", "selfillum.mesh"]
#: What the command imports later, on a thread while its rays run (a tree that imports
#: them up front has imported them with ``IMPORTS`` already): a part in one of them is
#: wrapped once its module is imported, not before (that would import it).
LATER = {"selfillum.solve.radiosity"}


def child(argv: list[str]) -> None:
    """Run ``selfillum correct argv`` here, the parts timed; JSON on stdout's last line."""
    import importlib
    import threading

    t0, c0 = time.perf_counter(), time.process_time()
    for m in IMPORTS:
        importlib.import_module(m)
    cli = importlib.import_module("selfillum.cli.main")

    t_imp, c_imp = time.perf_counter() - t0, time.process_time() - c0
    records: dict[str, list[float]] = {}
    stack: list[list[float]] = []  # [child wall, child cpu] of the open parts (main thread)
    main_thread = threading.main_thread()

    def wrap(label, fn):
        def timed(*a, **kw):
            if threading.current_thread() is not main_thread:
                return fn(*a, **kw)
            stack.append([0.0, 0.0])
            w, c = time.perf_counter(), time.process_time()
            try:
                return fn(*a, **kw)
            finally:
                dw, dc = time.perf_counter() - w, time.process_time() - c
                inner = stack.pop()
                r = records.setdefault(label, [0.0, 0.0])
                r[0] += dw - inner[0]
                r[1] += dc - inner[1]
                if stack:
                    stack[-1][0] += dw
                    stack[-1][1] += dc
        return timed

    def patch(obj, label, attr):
        *owner, name = attr.split(".")
        for o in owner:
            obj = getattr(obj, o)
        if hasattr(obj, name):  # an older tree may lack a function (then not timed)
            setattr(obj, name, wrap(label, getattr(obj, name)))

    later = {}
    for label, mod, attr, _ in PARTS:
        if mod in LATER and mod not in sys.modules:
            later.setdefault(mod, []).append((label, attr))
            continue
        try:
            obj = importlib.import_module(mod)
        except ImportError:  # an older tree may lack a module (then not timed)
            continue
        patch(obj, label, attr)
    if later:
        sys.meta_path.insert(0, _PatchOnImport(later, patch))
    w, c = time.perf_counter(), time.process_time()
    sys.argv = ["selfillum", *argv]
    cli.main()  # as the console script calls it (a process that exits next)
    total_w, total_c = time.perf_counter() - w, time.process_time() - c
    covered = [sum(r[i] for r in records.values()) for i in (0, 1)]
    records["other"] = [total_w - covered[0], total_c - covered[1]]
    records["imports"] = [t_imp, c_imp]
    print(json.dumps({"parts": records, "run": [total_w, total_c],
                      "before_imports": t0 - T_START, "trimesh": "trimesh" in sys.modules}),
          flush=True)


class _PatchOnImport:
    """A finder that patches the parts of a module of ``LATER`` once it is imported."""

    def __init__(self, later: dict, patch):
        self.later, self.patch = later, patch

    def find_spec(self, name, path=None, target=None):
        if name not in self.later:
            return None
        from importlib.machinery import PathFinder

        spec = PathFinder.find_spec(name, path, target)
        if spec is None:
            return None
        loader, parts, patch = spec.loader, self.later.pop(name), self.patch

        class Loader:
            def create_module(self, spec):
                return loader.create_module(spec)

            def exec_module(self, module):
                loader.exec_module(module)
                for label, attr in parts:
                    patch(module, label, attr)

        spec.loader = Loader()
        return spec


def _env(root: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(root)}
    env.pop("NUMBA_NUM_THREADS", None)
    if _NUMBA_THREADS is not None:
        env["NUMBA_NUM_THREADS"] = _NUMBA_THREADS
    return env


def run_command(root: Path, argv: list[str]) -> dict:
    env = _env(root)
    t = time.perf_counter()
    proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--child", *argv],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, cwd=root)
    lines = []
    for line in proc.stdout:  # the parts come as the child's last line, before its exit
        lines.append(line)
        if line.startswith("{"):
            break
    t_line = time.perf_counter()
    proc.stdout.read()
    if proc.wait() != 0:
        raise RuntimeError(f"the command failed: {''.join(lines)[-2000:]}")
    end = time.perf_counter()
    res = json.loads(lines[-1])
    res["wall"] = end - t
    # the interpreter's start and this script's top; the exit (freeing arrays, scene): serial
    res["parts"]["start-up"] = [t_line - t - res["run"][0] - res["parts"]["imports"][0], 0.0]
    res["parts"]["exit"] = [end - t_line, 0.0]
    return res


def serial_share(res: dict) -> float:
    parallel = {label for label, _, _, par in PARTS if par}
    return sum(w for k, (w, _) in res["parts"].items() if k not in parallel) / res["wall"]


def print_parts(tag: str, runs: list[dict]) -> None:
    best = min(runs, key=lambda r: r["wall"])
    parallel = {label for label, _, _, par in PARTS if par}
    walls = ", ".join(f"{r['wall']:.2f}" for r in runs)
    shares = ", ".join(f"{100 * serial_share(r):.0f}" for r in runs)
    print(f"\n{tag}: whole command {best['wall']:.2f} s (best of {len(runs)}; all: {walls}); "
          f"serial share {100 * serial_share(best):.0f} % (all: {shares} %); trimesh "
          f"{'imported' if best.get('trimesh', True) else 'not imported'}")
    order = ["start-up", "imports", "exit"] + list(dict.fromkeys(p[0] for p in PARTS)) + ["other"]
    for k in order:
        if k not in best["parts"]:
            continue
        w, c = best["parts"][k]
        kind = "parallel" if k in parallel else "serial"
        ratio = f"{c / w:4.2f}" if w > 0.01 and c > 0 else "   -"
        print(f"  {k:16s} {w:6.2f} s  {100 * w / best['wall']:5.1f} %  cpu/wall {ratio}  "
              f"{kind}")


def _timer(spent: dict[str, list[float]]):
    """``timed(label, fn)``: ``fn`` wrapped so that each call adds its wall and CPU
    seconds to ``spent[label]``."""
    def timed(label, fn):
        def call(*a, **kw):
            t, c = time.perf_counter(), time.process_time()
            try:
                return fn(*a, **kw)
            finally:
                r = spent.setdefault(label, [0.0, 0.0])
                r[0] += time.perf_counter() - t
                r[1] += time.process_time() - c
        return call
    return timed


def thread_efficiency(mesh, threads: list[int], repeat: int, rows) -> None:
    """``view_factors`` with each thread count; its one-thread parts timed apart: the
    tracer's set-up (mesh check, normals), the Embree scene (``scene arrays``: the
    checks and the padded float32 / uint32 arrays Embree reads in place, and Embree's
    BVH build, ``rtcCommitScene``, which runs on Embree's own TBB threads: its CPU over
    wall is printed), loading the kernels and the assembly of ``F``; the numba threads'
    kernel (sampling, tracing, filtering) is timed, and what is left (the mesh check,
    a little Python a chunk) counts as serial.
    Older trees (``embreex``'s scene) are timed as before: their buffer copy instead of
    the arrays."""
    from selfillum.transport import viewfactors as vf

    try:
        from resection.surface import embree
    except ImportError:  # a tree before the native binding
        return _thread_efficiency_embreex(mesh, threads, repeat, rows)

    spent: dict[str, list[float]] = {}
    timed = _timer(spent)

    from selfillum.transport import rowtrace

    lib = embree.library()
    saved = (vf.RowTracer.__init__, vf.RowTracer._start, vf._assemble, embree.Scene.__init__,
             lib.rtcCommitScene, rowtrace._trace_faces)
    vf.RowTracer.__init__ = timed("set-up", vf.RowTracer.__init__)
    vf.RowTracer._start = timed("scene + kernels", vf.RowTracer._start)
    vf._assemble = timed("F assembly", vf._assemble)
    embree.Scene.__init__ = timed("scene arrays", embree.Scene.__init__)
    lib.rtcCommitScene = timed("BVH build", lib.rtcCommitScene)
    # the numba threads' kernel; the rest (Python, the mesh check) is serial
    rowtrace._trace_faces = timed("kernels", rowtrace._trace_faces)
    asm = (rowtrace._sort_rows, rowtrace._fill_rows)  # inside "F assembly"
    rowtrace._sort_rows = timed("assembly kernels", rowtrace._sort_rows)
    rowtrace._fill_rows = timed("assembly kernels", rowtrace._fill_rows)
    try:
        times, parts = _thread_runs(vf, mesh, threads, repeat, rows, spent)
    finally:
        (vf.RowTracer.__init__, vf.RowTracer._start, vf._assemble, embree.Scene.__init__,
         lib.rtcCommitScene, rowtrace._trace_faces) = saved
        rowtrace._sort_rows, rowtrace._fill_rows = asm
    for p in parts.values():  # F assembly: its serial part; its kernels run on the threads
        if "assembly kernels" in p:
            p["F assembly"][0] -= p["assembly kernels"][0]
            p["kernels"][0] += p["assembly kernels"][0]
    for p in parts.values():  # the scene's own time, without the BVH inside it
        if "scene arrays" in p:
            p["scene arrays"][0] -= p.get("BVH build", [0.0, 0.0])[0]
    _print_threads(threads, rows, times, parts, "scene arrays")
    bare_embree_threads(mesh, threads, repeat)


def bare_embree_threads(mesh, threads: list[int], repeat: int, faces: int = 40_000,
                        k: int = 256) -> None:
    """The peer of the thread efficiency: bare Embree rays over the same thread counts.

    The rays of ``view_factors`` (the same RQMC rays, made beforehand in NumPy) of
    ``faces`` faces spread over the mesh, traced by ``resection.surface.embree.Scene.run``
    (``rtcIntersect1`` from a numba ``prange`` over blocks of rays: no sampling, no
    filtering, no assembly) with ``workers`` = each count, interleaved, best of
    ``repeat``. Its efficiency from 2 threads is what the machine gives Embree's rays
    alone: ``view_factors``' own efficiency is to be read against it."""
    import numpy as np

    from selfillum.mesh import face_normals
    from selfillum.transport.sampling import sample_rays
    from selfillum.transport.viewfactors import _OFFSET, RayScene

    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces)
    scene = RayScene(v, f)
    ids = np.linspace(0, len(f) - 1, min(faces, len(f))).astype(np.int64)
    tri = (v - scene.origin)[f[ids]]
    o, d, _ = sample_rays(tri, face_normals(mesh)[ids], k, face_ids=ids, seed=0,
                          offset=_OFFSET * float(np.ptp(v, axis=0).max()))
    o = np.ascontiguousarray(o, dtype=np.float32)
    d = np.ascontiguousarray(d, dtype=np.float32)
    scene.scene.run(o[:1000], d[:1000], workers=2)  # the kernel loaded
    best = dict.fromkeys(threads, float("inf"))
    for _ in range(repeat):
        for w in threads:
            t = time.perf_counter()
            scene.scene.run(o, d, workers=w)
            best[w] = min(best[w], time.perf_counter() - t)
    cores = len(os.sched_getaffinity(0))
    base = threads[0]
    print(f"\nbare Embree rays (the peer): {len(d) / 1e6:.1f} M rays of {ids.size:,} faces, "
          f"Scene.run on numba's threads, load average {os.getloadavg()[0]:.1f}:")
    for w in threads:
        eff = best[base] * min(base, cores) / (best[w] * min(w, cores))
        print(f"  {w:3d} threads: {best[w]:7.3f} s ({len(d) / best[w] / 1e6:6.1f} M rays/s)"
              f"  efficiency from {base}: {eff:.2f}")


def _thread_runs(vf, mesh, threads, repeat, rows, spent):
    """Best of ``repeat`` of ``view_factors`` at each thread count, interleaved, with the
    parts ``spent`` recorded for the best run."""
    times: dict[int, float] = {}
    parts: dict[int, dict] = {}
    vf.view_factors(mesh, 256, rows=rows[:1000], workers=2)  # kernels loaded
    for _ in range(repeat):
        for w in threads:
            spent.clear()
            t = time.perf_counter()
            vf.view_factors(mesh, 256, rows=rows, workers=w)
            dt = time.perf_counter() - t
            if dt < times.get(w, float("inf")):
                times[w], parts[w] = dt, {k: list(v) for k, v in spent.items()}
    return times, parts


def _thread_efficiency_embreex(mesh, threads, repeat, rows) -> None:
    """:func:`thread_efficiency` of a tree whose scenes are ``embreex``'s."""
    from embreex import rtcore_scene

    from resection.surface import visibility as vis
    from selfillum.transport import viewfactors as vf

    spent: dict[str, list[float]] = {}
    timed = _timer(spent)

    class Scene(rtcore_scene.EmbreeScene):  # the first query commits (builds the BVH)
        def run(self, *a, **kw):
            if self.is_committed:
                return super().run(*a, **kw)
            return timed("BVH build", super().run)(*a, **kw)

    saved = (vf.RowTracer.__init__, vf.RowTracer._start, vf._assemble, vis.TriangleMesh,
             vis.rtcore_scene)
    vf.RowTracer.__init__ = timed("set-up", vf.RowTracer.__init__)
    vf.RowTracer._start = timed("scene + kernels", vf.RowTracer._start)
    vf._assemble = timed("F assembly", vf._assemble)
    vis.TriangleMesh = timed("buffer copy", vis.TriangleMesh)
    vis.rtcore_scene = type("rtcore_scene", (), {"EmbreeScene": Scene})
    try:
        times, parts = _thread_runs(vf, mesh, threads, repeat, rows, spent)
    finally:
        (vf.RowTracer.__init__, vf.RowTracer._start, vf._assemble, vis.TriangleMesh,
         vis.rtcore_scene) = saved
    _print_threads(threads, rows, times, parts, "buffer copy")


def _print_threads(threads, rows, times, parts, scene_part: str) -> None:
    """Times, parts and efficiency of each thread count; Amdahl's bound from 2 to 16
    cores from the one-thread parts of the 2-thread run."""
    cores = os.cpu_count() or 1
    print(f"\nview_factors, {len(rows):,} rows, K = 256, {cores} cores, load average "
          f"{os.getloadavg()[0]:.1f}:")
    base = times.get(2)
    for w in threads:
        p = parts[w]
        if "kernels" in p:  # what is neither a named part nor the threads' kernels
            named = sum(p[k][0] for k in ("set-up", "scene + kernels", "F assembly", "kernels"))
            p["bookkeeping"] = [times[w] - named, 0.0]
        eff = (f"{base * 2 / (times[w] * min(w, cores)):.2f}" if base else "-")
        bvh = p.get("BVH build", [0.0, 0.0])
        print(f"  {w:2d} threads: {times[w]:6.2f} s (threads' kernels "
              f"{p.get('kernels', [0.0])[0]:.2f} s; one thread: set-up "
              f"{p['set-up'][0]:.2f} s, scene + "
              f"kernels {p['scene + kernels'][0]:.2f} s of which {scene_part} "
              f"{p.get(scene_part, [0.0])[0]:.2f} s and BVH build {bvh[0]:.2f} s at cpu/wall "
              f"{bvh[1] / max(bvh[0], 1e-9):.2f}, F assembly (serial part) "
              f"{p['F assembly'][0]:.2f} s, "
              f"mesh check and chunks' bookkeeping {p.get('bookkeeping', [0.0])[0]:.2f} s)  "
              f"efficiency from 2: {eff}")
    if base:
        p = parts[2]
        one = (p["set-up"][0] + p["scene + kernels"][0] + p["F assembly"][0]
               + p.get("bookkeeping", [0.0])[0])
        bvh = p.get("BVH build", [0.0, 0.0])[0]
        for what, ser in (("every one-thread part serial", one / base),
                          ("the BVH build parallel (Embree's TBB threads)",
                           (one - bvh) / base)):
            print(f"  serial share at 2 threads, {what}: {100 * ser:.0f} %: Amdahl bound "
                  f"from 2 to 16 cores {1 / (ser + (1 - ser) / 8):.1f}x "
                  f"(efficiency {1 / (ser + (1 - ser) / 8) / 8:.2f})")


def track_share(frames: list[int], workers: list[str]) -> None:
    """``resection track`` on the body of revolution (``bench_track_command``'s frames):
    wall and CPU seconds of the whole process (its children included) for each run length
    and ``--workers`` choice. The start-up is the 2-frame run; frames tracked in this
    process run one after the other on one thread (serial); CPU over wall tells how many
    cores the run kept busy."""
    import resource

    from bench_track_command import PERIOD, render

    cache = Path("/tmp/bench_track_revolution")
    cache.mkdir(parents=True, exist_ok=True)
    sc = render(cache)
    env = _env(ROOT)
    print(f"\nresection track (revolution body, 1280 x 800 frames), load average "
          f"{os.getloadavg()[0]:.1f}:")
    for n in frames:
        for w in workers:
            cmd = [sys.executable, "-m", "resection.cli", "track",
                   *[sc["frames"][k % PERIOD] for k in range(n)], "--camera", sc["camera"],
                   "--markers", sc["markers"], "--link", sc["link"], "--diameter", "5",
                   "--out", str(cache / f"amdahl_{n}_{w}"), "--no-progress", "--no-resume"]
            if w != "auto":
                cmd += ["--workers", w]
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t = time.perf_counter()
            subprocess.run(cmd, env=env, check=True, capture_output=True)
            wall = time.perf_counter() - t
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
            print(f"  {n:5d} frames, --workers {w}: wall {wall:6.2f} s, CPU {cpu:6.2f} s, "
                  f"cpu/wall {cpu / wall:4.2f}; load average {os.getloadavg()[0]:.1f}",
                  flush=True)


def correct_parts(args, argv: list[str], cache: Path, mesh) -> None:
    """The correct command of each ``--roots`` tree, parts timed, interleaved."""
    roots = [Path(r) for r in args.roots.split(",")]
    print(f"{len(mesh.faces):,} faces; load average at start {os.getloadavg()}")
    runs: dict[Path, list[dict]] = {r: [] for r in roots}
    argvs = {r: argv + ["--out", str(cache / f"corrected_amdahl_{i}.npy")]
             for i, r in enumerate(roots)}  # an output of its own each
    for r in roots:
        run_command(r, argvs[r])  # numba caches warm
    for _ in range(args.repeat):
        for r in roots:
            runs[r].append(run_command(r, argvs[r]))
    for r in roots:
        print_parts(str(r), runs[r])
    print(f"load average at end {os.getloadavg()}")


#: The floor of any command of the package that runs compiled code: the interpreter, NumPy,
#: numba and numba's start at its first compiled call (its target context: this imports
#: numba's NumPy support, and SciPy's linear algebra through it), the call loaded from
#: numba's cache.
FLOOR = ("import numpy as np\nfrom resection.surface.visibility import bounds\n"
         "bounds(np.zeros((3, 3)))\n")


#: The same floor without the package: a one-line kernel of a module of its own, cached.
BARE_KERNEL = ("import numba\n\n\n@numba.njit(cache=True)\ndef total(x):\n"
               "    return x.sum()\n")
BARE_FLOOR = "import numpy as np\nimport bare_kernel\nbare_kernel.total(np.zeros(3))\n"


def process_floor(root: Path, repeat: int = 5) -> None:
    """Print the best wall seconds of ``FLOOR``, of ``BARE_FLOOR`` (in a temporary folder,
    its kernel cached by a first run) and of an empty interpreter, each in a fresh process,
    interleaved (``repeat`` rounds)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        Path(tmp, "bare_kernel.py").write_text(BARE_KERNEL)
        runs = {"empty interpreter": ("pass", root), "floor": (FLOOR, root),
                "bare floor": (BARE_FLOOR, Path(tmp))}
        subprocess.run([sys.executable, "-c", BARE_FLOOR], check=True, cwd=tmp)  # cached
        best = dict.fromkeys(runs, float("inf"))
        for _ in range(repeat):
            for name, (code, cwd) in runs.items():
                t = time.perf_counter()
                subprocess.run([sys.executable, "-c", code], check=True, env=_env(root),
                               cwd=cwd)
                best[name] = min(best[name], time.perf_counter() - t)
    print(f"process floor ({root}): {best['floor']:.2f} s (the interpreter, NumPy, numba "
          f"and its start at the package's first compiled call); a one-line cached kernel "
          f"of a module of its own, without the package: {best['bare floor']:.2f} s; an "
          f"empty interpreter {best['empty interpreter']:.2f} s; best of {repeat}")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(sys.argv[2:])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, default=609_000)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--roots", default=str(ROOT),
                    help="comma-separated source trees to compare (default: this one)")
    ap.add_argument("--threads", default="", help="e.g. 1,2,4,8,16 (default: skip)")
    ap.add_argument("--vf-faces", type=int, default=0,
                    help="rows of view_factors in the thread bench (default all)")
    ap.add_argument("--cache", default="/tmp/bench_si_command")
    ap.add_argument("--track-frames", default="",
                    help="e.g. 2,2000: also time resection track (default: skip)")
    ap.add_argument("--track-workers", default="auto",
                    help="track's --workers values, e.g. auto,1,2")
    ap.add_argument("--skip-correct", action="store_true")
    args = ap.parse_args()
    if args.threads:  # numba's pool must hold the largest count (before numba loads)
        most = max(int(t) for t in args.threads.split(","))
        os.environ["NUMBA_NUM_THREADS"] = str(max(most, int(_NUMBA_THREADS or 0)))
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_si_command import files

    if args.track_frames:
        track_share([int(x) for x in args.track_frames.split(",")],
                    args.track_workers.split(","))
    cache = Path(args.cache) / str(args.faces)
    cache.mkdir(parents=True, exist_ok=True)
    f, mesh = files(args.faces, cache)
    argv = ["correct", "--mesh", f["mesh"], "--camera", f["camera"], "--image", f["image"],
            "--reflectance", "0.5", "--unpainted", f["unpainted"],
            "--quiet"]
    if not args.skip_correct:
        process_floor(Path(args.roots.split(",")[-1]))
        correct_parts(args, argv, cache, mesh)
    if args.threads:
        import numpy as np

        n = len(mesh.faces)
        rows = np.arange(n) if not args.vf_faces else \
            np.linspace(0, n - 1, args.vf_faces).astype(np.int64)
        thread_efficiency(mesh, [int(t) for t in args.threads.split(",")], args.repeat, rows)


if __name__ == "__main__":
    main()
