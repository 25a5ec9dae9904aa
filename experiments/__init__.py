"""Experiment runners on top of the service: ``paper_demo`` (``contact-skills demo``), its cases, stack, report."""
