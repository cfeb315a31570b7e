"""TransAM: transformer-based agent modeling for multi-agent RL, in JAX."""

__version__ = "0.1.0"
