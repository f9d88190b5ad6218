"""MuJoCo passive-force callbacks for the C twins, evaluated at every RK4 stage: the one-sided tyre (compiled, and
as a labelled Python reference :func:`python_tyre`) and sinusoidal joint torques (compiled).

MuJoCo has no element for a one-sided spring-damper, so the twins of the quarter car and of Nikravesh's double
A-arm add it in ``mjcb_passive``. A Python callback costs interpreter time per stage and cannot run on the worker
threads of ``mujoco.rollout`` or ``mujoco.batch`` (which require C callbacks); this module compiles the same law in C
(once per process, with the system's C compiler, against the headers and library shipped in the mujoco wheel) and
installs it through ``ctypes`` as MuJoCo's engineers recommend. The force law is the one of
:func:`particlesim.mechanism.forces.point_forces`:

    d = p . n - ground - radius;   f = -(k d + c v . n) n   while d < 0,

applied at a site through its translational Jacobian. Geometry and default constants (up to :data:`MAX_TYRES`
tyres) are set with :func:`set_tyres`; a model with a ``numeric`` element ``i`` of size 2 overrides tyre ``i``'s
stiffness and damping with it (:func:`tyre_numeric` writes the element), so every model of a batch can carry its
own tyre. The callback itself is stateless (it allocates on MuJoCo's own stack), so it is safe on every thread.
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

__all__ = ["MAX_TYRES", "MAX_DOF", "set_tyres", "install_tyres", "install_sine_torques", "uninstall", "compiled_library",
           "tyre_numeric", "python_tyre"]

MAX_TYRES = 8

_SOURCE = r"""
#include <math.h>
#include <mujoco/mujoco.h>

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

void ps_tyre_passive(const mjModel* m, mjData* d) {
  int nv = m->nv;
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
    double dist = p[0] * x[0] + p[1] * x[1] + p[2] * x[2] - p[3] - p[4];
    if (dist >= 0.0) continue;
    mj_jacSite(m, d, jac, NULL, tyre_site[i]);
    double vn = 0.0;
    for (int j = 0; j < nv; j++) {
      double jn = p[0] * jac[j] + p[1] * jac[nv + j] + p[2] * jac[2 * nv + j];
      vn += jn * d->qvel[j];
    }
    double f = -(p[5] * dist + p[6] * vn);
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


def set_tyres(tyres) -> None:
    """``tyres``: ``(site id, normal (3,), ground, radius, stiffness, damping)`` per tyre."""
    lib = compiled_library()
    if len(tyres) > MAX_TYRES:
        raise ValueError(f"at most {MAX_TYRES} tyres, got {len(tyres)}")
    for i, (site, normal, ground, radius, k, c) in enumerate(tyres):
        n = np.asarray(normal, dtype=float)
        lib.ps_set_tyre(ctypes.c_int(i), ctypes.c_int(int(site)), *(ctypes.c_double(float(v)) for v in
                                                  (n[0], n[1], n[2], ground, radius, k, c)))
    lib.ps_set_count(ctypes.c_int(len(tyres)))


_CALLBACK = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)


def install_tyres(tyres) -> None:
    """Set the tyres and install the compiled callback as ``mjcb_passive`` (global to the process, as MuJoCo's
    callbacks are). The bindings take a ctypes function and install its C address, so MuJoCo calls the compiled
    code directly, on any thread."""
    set_tyres(tyres)
    mujoco.set_mjcb_passive(ctypes.cast(compiled_library().ps_tyre_passive, _CALLBACK))


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
