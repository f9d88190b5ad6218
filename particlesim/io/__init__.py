"""Model files in and out: URDF import, MuJoCo/MJX twins."""
