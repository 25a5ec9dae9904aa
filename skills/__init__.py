"""The science: pure functions, no I/O (segmentation, compliant frames, DMPs, parameterization, control law)."""
