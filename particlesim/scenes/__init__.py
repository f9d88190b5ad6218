"""Ready-made models: Krang (report frames and URDF)."""

from .krang import krang_report, krang_report_params, krang_urdf

__all__ = ["krang_report", "krang_report_params", "krang_urdf"]
