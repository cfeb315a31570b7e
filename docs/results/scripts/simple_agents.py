"""Hand-written controlled agents on Spread against one or more partner populations: uniformly
random, always "no move", head for the nearest landmark, and the landmark rule. Prints each
one's mean return ± its standard error (see
docs/notes/2026-12-slow-policy-learning-default-population.md).

    python docs/results/scripts/simple_agents.py default runs/authors-pop

Now a front for hand_agents.py (the same agents, episodes and output for Spread, and rules for
the other games): this is `hand_agents.py POPULATION ...`.
"""

from __future__ import annotations

from hand_agents import main

if __name__ == "__main__":
    main()
