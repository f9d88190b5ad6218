"""MuJoCo passive-force callbacks for the C twins, evaluated at every RK4 stage: the one-sided tyre (compiled, and
as a labelled Python reference :func:`python_tyre`) and sinusoidal joint torques (compiled).

MuJoCo has no element for a one-sided spring-damper, so the twins of the quarter car and of Nikravesh's double
A-arm add it in ``mjcb_passive``. A Python callback costs interpreter time per stage and cannot run on the worker
threads of ``mujoco.rollout`` or ``mujoco.batch`` (which require C callbacks); this module compiles the same law in C
(once per process, with the system's C compiler, against the headers and library shipped in the mujoco wheel) and
installs it through ``ctypes`` as MuJoCo's engineers recommend. The force law is the one of
:func:`particlesim.mechanism.forces.point_forces`:

    d = p . n - ground - radius - h(t);   f = -(k d + c (v . n - h'(t))) n   while d < 0,

applied at a site through its translational Jacobian, ``h`` the tyre's road (0 for a plane): a sum of the roads of
:mod:`particlesim.scenes.roads` (``Bump``, ``SineSum``, ``Sum`` of those), evaluated in closed form with its time
derivative at the stage time ``d->time`` (:func:`road_terms`; the same formulas, the same parameters). Geometry,
roads and default constants (up to :data:`MAX_TYRES` tyres) are set with :func:`set_tyres`; a model with a
``numeric`` element ``i`` of size 2 overrides tyre ``i``'s stiffness and damping with it (:func:`tyre_numeric` writes
the element), so every model of a batch can carry its own tyre. The callback itself is stateless (it allocates on
MuJoCo's own stack), so it is safe on every thread.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import tempfile
from pathlib import Path

import mujoco
import numpy as np

__all__ = ["MAX_TYRES", "MAX_DOF", "MAX_ROAD_TERMS", "MAX_ROAD_WAVES", "set_tyres", "install_tyres",
           "install_sine_torques", "uninstall", "compiled_library", "tyre_numeric", "python_tyre", "road_terms",
           "compiled_roads"]

MAX_TYRES = 8

_SOURCE = r"""
#include <math.h>
#include <mujoco/mujoco.h>
#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#define MAX_TYRES 8
static int n_tyres = 0;
static int tyre_site[MAX_TYRES];
static double tyre_par[MAX_TYRES][7];  /* nx ny nz ground radius k c */

void ps_set_tyre(int i, int site, double nx, double ny, double nz, double ground, double radius, double k,
                 double c) {
  tyre_site[i] = site;
  tyre_par[i][0] = nx; tyre_par[i][1] = ny; tyre_par[i][2] = nz;
  tyre_par[i][3] = ground; tyre_par[i][4] = radius; tyre_par[i][5] = k; tyre_par[i][6] = c;
}

void ps_set_count(int n) { n_tyres = n; }

/* road heights h_i(t) and rates h_i'(t) under the tyres: terms of particlesim.scenes.roads, summed per tyre.
   kind 0, Bump (height, start, duration); kind 1, SineSum (speed, offset, start, fade) of waves w0 .. w0+nw-1
   (amplitude, wavenumber, phase) */
#define MAX_ROAD_TERMS 64
#define MAX_ROAD_WAVES 4096
static int n_road = 0;
static int road_tyre[MAX_ROAD_TERMS], road_kind[MAX_ROAD_TERMS], road_w0[MAX_ROAD_TERMS], road_nw[MAX_ROAD_TERMS];
static double road_par[MAX_ROAD_TERMS][4];
static double road_wave[MAX_ROAD_WAVES][3];

void ps_set_road_count(int n) { n_road = n; }

void ps_set_road(int j, int tyre, int kind, double a, double b, double c, double e, int w0, int nw) {
  road_tyre[j] = tyre; road_kind[j] = kind; road_w0[j] = w0; road_nw[j] = nw;
  road_par[j][0] = a; road_par[j][1] = b; road_par[j][2] = c; road_par[j][3] = e;
}

void ps_set_wave(int w, double amplitude, double wavenumber, double phase) {
  road_wave[w][0] = amplitude; road_wave[w][1] = wavenumber; road_wave[w][2] = phase;
}

static double clip01(double u) { return u < 0.0 ? 0.0 : (u > 1.0 ? 1.0 : u); }

void ps_road_eval(double t, double* h, double* rate) {
  for (int i = 0; i < MAX_TYRES; i++) { h[i] = 0.0; rate[i] = 0.0; }
  for (int j = 0; j < n_road; j++) {
    const double* p = road_par[j];
    double v, dv = 0.0;
    if (road_kind[j] == 0) {  /* height (1 - cos(2 pi s)) / 2, s = clip((t - start) / duration) */
      double u = (t - p[1]) / p[2], s = clip01(u);
      v = p[0] * 0.5 * (1.0 - cos(2.0 * M_PI * s));
      if (u > 0.0 && u < 1.0) dv = p[0] * 0.5 * (sin(2.0 * M_PI * s) * (2.0 * M_PI / p[2]));
    } else {  /* w(t) sum_k a_k sin(k_k x + phi_k), x = speed (t - start) - offset, w = smoothstep((t-start)/fade) */
      double x = p[0] * (t - p[2]) - p[1], u = (t - p[2]) / p[3], s = clip01(u);
      double w = 0.5 - 0.5 * cos(M_PI * s), dw = (u > 0.0 && u < 1.0) ? 0.5 * sin(M_PI * s) * (M_PI / p[3]) : 0.0;
      double sum = 0.0, dsum = 0.0;
      for (int k = road_w0[j]; k < road_w0[j] + road_nw[j]; k++) {
        double arg = road_wave[k][1] * x + road_wave[k][2];
        sum += road_wave[k][0] * sin(arg);
        dsum += road_wave[k][0] * (cos(arg) * (road_wave[k][1] * p[0]));
      }
      v = w * sum;
      dv = dw * sum + w * dsum;
    }
    h[road_tyre[j]] += v;
    rate[road_tyre[j]] += dv;
  }
}

void ps_tyre_passive(const mjModel* m, mjData* d) {
  int nv = m->nv;
  double road[MAX_TYRES], road_rate[MAX_TYRES];
  ps_road_eval(d->time, road, road_rate);
  mj_markStack(d);
  mjtNum* jac = mj_stackAllocNum(d, 3 * nv);
  for (int i = 0; i < n_tyres; i++) {
    double p[7];
    for (int k = 0; k < 7; k++) p[k] = tyre_par[i][k];
    /* per-model stiffness and damping: numeric i of the model, if it has one of size >= 2 */
    if (m->nnumeric > i && m->numeric_size[i] >= 2) {
      p[5] = m->numeric_data[m->numeric_adr[i]];
      p[6] = m->numeric_data[m->numeric_adr[i] + 1];
    }
    const mjtNum* x = d->site_xpos + 3 * tyre_site[i];
    double dist = p[0] * x[0] + p[1] * x[1] + p[2] * x[2] - p[3] - p[4] - road[i];
    if (dist >= 0.0) continue;
    mj_jacSite(m, d, jac, NULL, tyre_site[i]);
    double vn = 0.0;
    for (int j = 0; j < nv; j++) {
      double jn = p[0] * jac[j] + p[1] * jac[nv + j] + p[2] * jac[2 * nv + j];
      vn += jn * d->qvel[j];
    }
    double f = -(p[5] * dist + p[6] * (vn - road_rate[i]));
    for (int j = 0; j < nv; j++) {
      double jn = p[0] * jac[j] + p[1] * jac[nv + j] + p[2] * jac[2 * nv + j];
      d->qfrc_passive[j] += jn * f;
    }
  }
  mj_freeStack(d);
}

/* joint torques tau_j(t) = A_j sin(w_j t + phi_j) on every dof, at the stage time d->time */
#define MAX_DOF 256
static int n_sine = 0;
static double sine_par[MAX_DOF][3];  /* amplitude, angular frequency, phase */

void ps_set_sine(int j, double a, double w, double phi) {
  sine_par[j][0] = a; sine_par[j][1] = w; sine_par[j][2] = phi;
}

void ps_set_sine_count(int n) { n_sine = n; }

void ps_sine_passive(const mjModel* m, mjData* d) {
  int n = n_sine < m->nv ? n_sine : m->nv;
  for (int j = 0; j < n; j++)
    if (sine_par[j][0] != 0.0) d->qfrc_passive[j] += sine_par[j][0] * sin(sine_par[j][1] * d->time + sine_par[j][2]);
}
"""

_LIB: ctypes.CDLL | None = None


def _mujoco_library() -> Path:
    root = Path(mujoco.__file__).parent
    found = sorted(root.glob("libmujoco.so*")) + sorted(root.glob("libmujoco*.dylib"))
    if not found:
        raise RuntimeError(f"no MuJoCo shared library in {root}")
    return found[0]


def compiled_library() -> ctypes.CDLL:
    """The compiled callback library (built on first use into a per-user cache directory)."""
    global _LIB
    if _LIB is not None:
        return _LIB
    lib = _mujoco_library()
    include = Path(mujoco.__file__).parent / "include"
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "particlesim"
    cache.mkdir(parents=True, exist_ok=True)
    tag = f"{mujoco.__version__}-{hashlib.sha256(_SOURCE.encode()).hexdigest()[:12]}"
    out = cache / f"ps_tyre_{tag}.so"
    if not out.exists():
        with tempfile.TemporaryDirectory() as tmp:
            src = Path(tmp) / "ps_tyre.c"
            src.write_text(_SOURCE)
            tmp_out = Path(tmp) / out.name
            cc = os.environ.get("CC", "cc")
            cmd = [cc, "-O2", "-shared", "-fPIC", f"-I{include}", str(src), "-o", str(tmp_out),
                   f"-L{lib.parent}", f"-l:{lib.name}", f"-Wl,-rpath,{lib.parent}", "-lm"]
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode:
                raise RuntimeError(f"compiling the MuJoCo tyre callback failed ({' '.join(cmd)}):\n{res.stderr}")
            os.replace(tmp_out, out)
    _LIB = ctypes.CDLL(str(out))
    return _LIB


def set_tyres(tyres, roads=None) -> None:
    """``tyres``: ``(site id, normal (3,), ground, radius, stiffness, damping)`` per tyre; ``roads``: per tyre a
    road of :mod:`particlesim.scenes.roads` or ``None`` (a plane; default for all), see :func:`road_terms`."""
    lib = compiled_library()
    if len(tyres) > MAX_TYRES:
        raise ValueError(f"at most {MAX_TYRES} tyres, got {len(tyres)}")
    roads = [None] * len(tyres) if roads is None else list(roads)
    if len(roads) != len(tyres):
        raise ValueError(f"roads: one per tyre (None for a plane), got {len(roads)} for {len(tyres)} tyres")
    terms = [(i, kind, par, waves) for i, road in enumerate(roads) if road is not None
             for kind, par, waves in road_terms(road)]
    n_waves = sum(len(w) for *_, w in terms)
    if len(terms) > MAX_ROAD_TERMS or n_waves > MAX_ROAD_WAVES:
        raise ValueError(f"roads: at most {MAX_ROAD_TERMS} terms and {MAX_ROAD_WAVES} sinusoids in all, got "
                         f"{len(terms)} and {n_waves}")
    for i, (site, normal, ground, radius, k, c) in enumerate(tyres):
        n = np.asarray(normal, dtype=float)
        lib.ps_set_tyre(ctypes.c_int(i), ctypes.c_int(int(site)), *(ctypes.c_double(float(v)) for v in
                                                  (n[0], n[1], n[2], ground, radius, k, c)))
    w0 = 0
    for j, (i, kind, par, waves) in enumerate(terms):
        for w, (a, kw, ph) in enumerate(waves):
            lib.ps_set_wave(ctypes.c_int(w0 + w), *(ctypes.c_double(v) for v in (a, kw, ph)))
        lib.ps_set_road(ctypes.c_int(j), ctypes.c_int(i), ctypes.c_int(_KINDS.index(kind)),
                        *(ctypes.c_double(v) for v in par), ctypes.c_int(w0), ctypes.c_int(len(waves)))
        w0 += len(waves)
    lib.ps_set_road_count(ctypes.c_int(len(terms)))
    lib.ps_set_count(ctypes.c_int(len(tyres)))


_CALLBACK = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)


def install_tyres(tyres, roads=None) -> None:
    """Set the tyres (and their roads, :func:`set_tyres`) and install the compiled callback as ``mjcb_passive``
    (global to the process, as MuJoCo's callbacks are). The bindings take a ctypes function and install its C
    address, so MuJoCo calls the compiled code directly, on any thread."""
    set_tyres(tyres, roads)
    mujoco.set_mjcb_passive(ctypes.cast(compiled_library().ps_tyre_passive, _CALLBACK))


MAX_ROAD_TERMS = 64
MAX_ROAD_WAVES = 4096
_KINDS = ("bump", "sines")


def _scalar(road, field: str) -> float:
    v = np.asarray(getattr(road, field), dtype=float)
    if v.shape != () or not np.isfinite(v):
        raise ValueError(f"{type(road).__name__}.{field} must be one finite number, got {v!r}")
    return float(v)


def road_terms(road) -> list[tuple[str, tuple, list]]:
    """The compiled callback's terms of ``road``, read from its arrays: ``("bump", (height, start, duration), [])``
    for a :class:`~particlesim.scenes.roads.Bump`, ``("sines", (speed, offset, start, fade), [(amplitude,
    wavenumber, phase), ...])`` for a :class:`~particlesim.scenes.roads.SineSum`, a
    :class:`~particlesim.scenes.roads.Sum` flattened into its parts' terms. Any other road (a function, a
    subclass, another Module) raises ``NotImplementedError`` naming its type: the callback evaluates these closed
    forms only."""
    from ..scenes import roads as rd

    if type(road) is rd.Sum:
        return [term for part in road.roads for term in road_terms(part)]
    if type(road) is rd.Bump:
        par = tuple(_scalar(road, f) for f in ("height", "start", "duration"))
        if par[2] <= 0.0:
            raise ValueError(f"Bump.duration must be positive, got {par[2]}")
        return [("bump", par, [])]
    if type(road) is rd.SineSum:
        par = tuple(_scalar(road, f) for f in ("speed", "offset", "start", "fade"))
        if par[3] <= 0.0:
            raise ValueError(f"SineSum.fade must be positive, got {par[3]}")
        waves = [np.asarray(getattr(road, f), dtype=float) for f in ("amplitude", "wavenumber", "phase")]
        if not (waves[0].ndim == 1 and waves[0].shape == waves[1].shape == waves[2].shape) or \
                not all(np.all(np.isfinite(w)) for w in waves):
            raise ValueError("SineSum: amplitude, wavenumber and phase must be finite and of one length (K,), got "
                             f"shapes {[w.shape for w in waves]}")
        return [("sines", par, [tuple(float(v) for v in row) for row in np.stack(waves, axis=1)])]
    raise NotImplementedError(f"a road of type {type(road).__name__} has no compiled form: the tyre callback "
                              "evaluates Bump, SineSum and Sum of those (particlesim.scenes.roads)")


def compiled_roads(t: float) -> tuple[np.ndarray, np.ndarray]:
    """The compiled road heights and their time derivatives ``(MAX_TYRES,)`` each at time ``t``, of the roads last
    set (:func:`set_tyres`; zero for a tyre without one): what the callback reads at a stage time."""
    lib = compiled_library()
    h, rate = np.zeros(MAX_TYRES), np.zeros(MAX_TYRES)
    ptr = ctypes.POINTER(ctypes.c_double)
    lib.ps_road_eval(ctypes.c_double(float(t)), h.ctypes.data_as(ptr), rate.ctypes.data_as(ptr))
    return h, rate


MAX_DOF = 256


def install_sine_torques(amplitude, omega, phase) -> None:
    """Install ``tau_j(t) = amplitude_j sin(omega_j t + phase_j)`` on dof ``j`` (MuJoCo's dof order) as a compiled
    ``mjcb_passive``, evaluated at every RK4 stage at the stage time; runs on ``mujoco.rollout``'s threads."""
    a, w, ph = (np.asarray(v, dtype=float).reshape(-1) for v in (amplitude, omega, phase))
    if not (a.shape == w.shape == ph.shape) or a.size > MAX_DOF or not np.all(np.isfinite(np.r_[a, w, ph])):
        raise ValueError(f"amplitude, omega, phase: equal lengths <= {MAX_DOF}, finite")
    lib = compiled_library()
    for j in range(a.size):
        lib.ps_set_sine(ctypes.c_int(j), ctypes.c_double(a[j]), ctypes.c_double(w[j]), ctypes.c_double(ph[j]))
    lib.ps_set_sine_count(ctypes.c_int(a.size))
    mujoco.set_mjcb_passive(ctypes.cast(lib.ps_sine_passive, _CALLBACK))


def uninstall() -> None:
    """Remove the passive callback."""
    mujoco.set_mjcb_passive(None)


def tyre_numeric(xml: str, stiffness: float, damping: float) -> str:
    """MJCF text with a ``numeric`` element holding the tyre's stiffness and damping (tyre 0), inserted before
    ``</mujoco>``; change them per model in ``MjModel.numeric_data[0:2]``."""
    element = f'<custom><numeric name="ps_tyre0" data="{float(stiffness)!r} {float(damping)!r}"/></custom>'
    head, sep, tail = xml.rpartition("</mujoco>")
    if not sep:
        raise ValueError("not an MJCF document: no </mujoco>")
    return head + element + sep + tail


def python_tyre(site: int, normal, ground: float, radius: float, stiffness: float, damping: float):
    """The same tyre law as a Python ``mjcb_passive`` (install with ``mujoco.set_mjcb_passive``): the reference the
    compiled callback is tested against, and the labelled Python-callback rows of the benchmarks. It costs
    interpreter time per stage and cannot run on ``mujoco.rollout``'s worker threads."""
    n = np.asarray(normal, dtype=float)
    jacp = np.zeros((3, 0))

    def cb(m, d):
        nonlocal jacp
        if jacp.shape[1] != m.nv:
            jacp = np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jacp, None, site)
        dist = d.site_xpos[site] @ n - ground - radius
        if dist < 0.0:
            jn = n @ jacp
            d.qfrc_passive[:] += jn * (-(stiffness * dist + damping * (jn @ d.qvel)))

    return cb
