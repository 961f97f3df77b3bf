"""Simulators that make data with known truth for the bundled models."""
