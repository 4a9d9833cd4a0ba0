from sb3_icrl.pi_lagrangian.pi_lagrangian import PILagrangian

__all__ = ["PILagrangian"]
