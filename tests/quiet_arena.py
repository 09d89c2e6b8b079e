"""Arena odometry without noise or biases, for tests that look at one effect alone."""

QUIET_ODOMETRY = {
    "sigma_x_per_sqrt_m": 0.0,
    "sigma_y_per_sqrt_m": 0.0,
    "sigma_theta_per_sqrt_m": 0.0,
    "sigma_theta_per_sqrt_rad": 0.0,
    "sigma_per_sqrt_s": (1e-9, 1e-9, 1e-9),
    "heading_bias_per_m": 0.0,
    "scale_bias": 0.0,
}
