"""Text to a humanoid robot: a motion retargeted onto a robot described by MJCF (the Unitree G1 and H1 ship with
the package), checked in MuJoCo, written as a ``qpos`` trajectory. Needs the ``robot`` extra (MuJoCo)."""
