"""Sensor models: one module per factor kind, each giving whitened Jacobian blocks at the nominal
motion (``blocks``) and its nonlinear residual (for finite-difference tests and simulation)."""
