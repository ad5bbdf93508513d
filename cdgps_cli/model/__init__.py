"""Physical models: kinematics p(q) and dp/dq, modal dynamics, antenna points, GPS models."""
