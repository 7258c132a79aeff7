"""The MSCKF filter in the style of OpenVINS (numba kernels), its front-end and native initializers.

Modules: config (MsckfConfig), state / state_helper (clones, landmarks, EKF update, marginalisation),
propagator (RK4 mean, analytic Phi/Qd), triangulation, measurement (Jacobians, nullspace projection),
landmark_repr (anchored inverse depth), update_msckf / update_slam / update_zupt, health, estimator
(MsckfEstimator: the one entry point), tracker and init_* (front-end and initializers).
Import the submodules directly, e.g. ``from runtime.msckf.estimator import MsckfEstimator``.
"""
