"""Configuration of the hook filter: process noise, measurement noise, initial uncertainty,
rates, gates and the EKF/UKF options (document 002 4.6)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from boomtip.data.crane_model import CraneParams
from boomtip.data.installation import CraneSpec

__all__ = ["ProcessNoiseConfig", "MeasurementNoiseConfig", "InitialUncertaintyConfig", "HookFilterConfig"]


class ProcessNoiseConfig(BaseModel):
    """Q per document 002 4.6.2 (eqs. 4.29-4.30).

    Two defaults differ from the document (``document_002()`` gives its exact values):
    the vessel jerk sigma is the document's own worst-case estimate 0.14 rad/s^3 (2 deg,
    4 s) instead of its "conservatively increased" 0.5, and the joint jerk uses
    ``0.2 a_max / Ts`` instead of ``0.5 a_max / Ts``.  Both lower the noise of the
    estimated boom-tip acceleration (the MRU rate noise times a 150 m lever arm and the
    0.1 deg encoder noise dominate it), and so the hook velocity's error, without gating
    good fixes.
    """
    model_config = ConfigDict(extra="forbid")  # a misspelt key is an error, not a default

    sigma_sway_acc_rad_s2: float = 1e-4
    sigma_deflection_acc_rad_s2: float = 3e-3
    sigma_vessel_jerk_rad_s3: float = 0.14
    slew_acc_max_rad_s2: float = 0.01
    luff_acc_max_rad_s2: float = 0.0005
    hoist_acc_max_m_s2: float = 0.1125
    joint_jerk_scale: float = 0.2  # sigma_j = scale * a_max / Ts (document: 0.5)
    gamma_joint: float = 0.1
    gamma_vessel: float = 1.0
    nominal_dt_s: float = 0.005  # Ts in sigma_j = scale a_max / Ts
    full_blocks: bool = False  # True: correlated DWNA/DWNJ blocks; False: diagonal as in 002

    @classmethod
    def document_002(cls) -> "ProcessNoiseConfig":
        return cls(sigma_vessel_jerk_rad_s3=0.5, joint_jerk_scale=0.5)


class MeasurementNoiseConfig(BaseModel):
    """Filter R (document 002 eqs. 4.31-4.33, with its safety margins)."""
    model_config = ConfigDict(extra="forbid")  # a misspelt key is an error, not a default

    sigma_lidar_m: float = 0.015
    sigma_slew_rad: float = 2e-3
    sigma_luff_rad: float = 2e-3
    sigma_hoist_m: float = 0.01
    sigma_mru_angle_rad: float = 4e-4
    sigma_mru_rate_rad_s: float = 5e-4


class InitialUncertaintyConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")  # a misspelt key is an error, not a default
    sigma_sway_rad: float = 0.01
    sigma_sway_rate_rad_s: float = 0.05
    sigma_joint_rate: float = 0.02  # rad/s or m/s
    sigma_joint_acc: float = 0.01  # rad/s^2 (m/s^2 for the hoist: x10)
    sigma_vessel_acc_rad_s2: float = 0.02
    sigma_deflection_rad: float = 0.005
    sigma_deflection_rate_rad_s: float = 0.005


class HookFilterConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")  # a misspelt key is an error, not a default
    process: ProcessNoiseConfig = Field(default_factory=ProcessNoiseConfig)
    measurement: MeasurementNoiseConfig = Field(default_factory=MeasurementNoiseConfig)
    initial: InitialUncertaintyConfig = Field(default_factory=InitialUncertaintyConfig)
    predict_rate_hz: float = 200.0
    # 1-sigma of the levelling's constant tilt (mount survey + MRU static accuracy, rad): a bias
    # no averaging removes, added to the reported covariance across the rope (l sigma per axis)
    levelling_bias_sigma_rad: float = Field(0.0, ge=0.0)
    # the rope's length beyond what the hoist reads (fusion/rope_strain.py), learnt from the block
    # fixes: an offset (the fitted block point off the rope's end) and a strain (2e-3: 23 cm at
    # 115 m, a reeving ten times softer than stated under a heavy hook), their prior 1-sigmas
    # and random walks (a load picked up or set down); both 0: the hoist as read
    rope_offset_sigma_m: float = Field(0.2, ge=0.0, le=5.0)
    rope_strain_sigma: float = Field(2e-3, ge=0.0, le=0.1)
    rope_offset_walk_m_per_sqrt_s: float = Field(1e-3, ge=0.0)
    rope_strain_walk_per_sqrt_s: float = Field(5e-5, ge=0.0)
    lidar_gate_probability: float = 0.9999  # chi-square (3 dof) gate on the LiDAR innovation
    reacquire_after_rejections: int = 10  # consecutive gated LiDAR fixes -> re-initialise the sway
    # continuous Jacobian of the equations of motion (fusion/models/jacobian.py): "autodiff" and
    # "complex_step" are both exact to machine precision (they agree to ~1e-15); autodiff is
    # ~5x cheaper.  "numeric": central differences (benchmark variant).
    jacobian: Literal["autodiff", "complex_step", "numeric"] = "autodiff"
    # re-evaluate the continuous Jacobian A (and the model's derivative there) at most this
    # often: EKF at a prediction, F rebuilt from the cached A when dt changes; UKF at a window's
    # start, for its outputs, its Q and its midpoint. 0 = at every prediction (every window).
    # 50 ms: the hook's estimate within a fraction of a millimetre of a shorter interval's,
    # as accurate and as consistent
    jacobian_interval_s: float = Field(0.05, ge=0.0)
    # UKF sigma-point propagation: "generated" (fusion/models/batched_model.py, the tip's
    # kinematics once per step) or "core" (the crane model's core on arrays, once per stage:
    # benchmark variant); the same operations per element, the same result
    ukf_model: Literal["generated", "core"] = "generated"
    # the prediction's integrator (both filters): "rk4" (document 002 4.4) or "midpoint" (the
    # explicit midpoint rule, two evaluations of the crane model per step instead of four).
    integrator: Literal["rk4", "midpoint"] = "midpoint"
    # EKF mean: "jacobian": carried by the F of the covariance (A, refreshed every
    # jacobian_interval_s) about the model's own derivative at A's state, an affine step (the
    # model's curvature over 20 ms is micrometres of the hook); "model": the integrator on the
    # crane model every step
    ekf_mean: Literal["jacobian", "model"] = "jacobian"
    # UKF prediction window: the sigma points step once per window and the MRU and encoder
    # samples inside it are applied together at its end (each as its chain's state extrapolated
    # back to the sample's time: fusion/models/linear_chains.py); a LiDAR frame closes the window
    # at its time; the outputs inside a window apply each sample to the window's start carried
    # by the model's linear part. 1 / predict_rate_hz (or less): a sigma-point step and an
    # update per sample.
    ukf_window_s: float = Field(0.025, ge=0.0)
    # UKF with the midpoint rule and a window: "linearised": the second stage's accelerations
    # are the first's plus the model's Jacobian at the mean (the window's, for its outputs) times
    # the half step's displacement (one model evaluation on the sigma points per window instead
    # of two; fusion/models/batched_model.py); "model": the second stage on the model
    ukf_midpoint: Literal["model", "linearised"] = "linearised"
    ukf_alpha: float = 1e-3
    ukf_beta: float = 2.0
    ukf_kappa: float = 0.0


def nominal_crane_params(crane: CraneSpec, flexible: bool = True) -> CraneParams:
    """The filter's crane: the installation's nominal geometry and dynamics (Table 4.1)."""
    return CraneParams(m=crane.dynamics.hook_mass_kg, m_b=crane.dynamics.boom_mass_kg, L=crane.geometry.boom_length_m,
                       b=crane.geometry.boom_foot_offset_m, h=crane.geometry.boom_foot_height_m, c=crane.geometry.crane_base_m,
                       k_f=crane.dynamics.boom_stiffness_nm_per_rad, c_f=crane.dynamics.boom_damping, flexible=flexible)
