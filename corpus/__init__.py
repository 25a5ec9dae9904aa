"""Demonstrations with known ground truth (analytic, no physics engine): the corpus the learning is judged on.

Test-data generators, kept out of ``skills/`` (the science never imports them): ``synthetic`` (the paper's
scenarios), ``kinesthetic`` (what a hand-guided arm with a wrist sensor records).
"""
