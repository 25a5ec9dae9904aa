"""Demonstrations with known ground truth (analytic, no physics engine): the corpus the learning is judged on.

Test-data generators, kept out of ``skills/`` (the science never imports them; ``tests/test_layers.py``):

- ``families`` — the ground-truth corpus: every family of strokes on planes and contours on curved parts, and
  human-like recordings written as files (``corpus_cases``, ``random_case``), built from ``build`` and
  ``recording``, recorded in ``case`` (``CorpusCase``, ``TruthSegment``, the segment rules);
- ``scoring`` — a learned skill against a case's truth (type, segments, boundary, normal and force errors);
- ``synthetic`` — the paper's scenarios (a plane, two planes, a cylinder);
- ``kinesthetic`` — what a hand-guided arm with a wrist sensor records (its hand and sensor models are shared).
"""
