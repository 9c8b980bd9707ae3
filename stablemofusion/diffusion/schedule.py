"""The training noise schedule: diffusers' DDPM scheduler with the paper's settings."""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class ScheduleConfig:
    """DDPM forward process: T steps, linear betas, the model predicts x0 ("sample")."""

    num_train_timesteps: int = 1000
    beta_start: float = 1e-4
    beta_end: float = 0.02
    beta_schedule: str = "linear"
    prediction_type: str = "sample"


def make_train_scheduler(cfg: ScheduleConfig | None = None):
    """A diffusers DDPMScheduler for adding noise during training (``add_noise(x0, noise, t)``)."""
    from diffusers import DDPMScheduler

    return DDPMScheduler(**asdict(cfg or ScheduleConfig()), clip_sample=False)
