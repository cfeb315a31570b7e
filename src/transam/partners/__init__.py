"""Partner policies (heuristic and learned) and the populations built from them."""

from transam.envs.population import Member, PolicyFn, Population, Team

__all__ = ["Member", "PolicyFn", "Population", "Team"]
