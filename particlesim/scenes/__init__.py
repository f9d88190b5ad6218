"""Ready-made models, one module each: the quarter-car double wishbone (Attia §3), Nikravesh's planar double
A-arm, Andrews' squeezer and the IFToMM benchmark problems (A01-A05, a slider-crank), serial chains, free rigid
bodies and tops, the dropped two-mass suspension, a full vehicle on four double wishbones, and Krang (report frames
and URDF)."""

from . import andrews, chains, iftomm, krang, nikravesh, quarter_car, rigid, suspension_drop, vehicle
from .krang import krang_report, krang_report_params, krang_urdf

__all__ = ["andrews", "chains", "iftomm", "krang", "nikravesh", "quarter_car", "rigid", "suspension_drop", "vehicle",
           "krang_report", "krang_report_params", "krang_urdf"]
