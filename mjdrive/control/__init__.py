"""Classical control and planning: pure pursuit, speed control, (later) LQR, MPC and the autopilot."""

from mjdrive.control.pure_pursuit import PurePursuit, SpeedController

__all__ = ["PurePursuit", "SpeedController"]
