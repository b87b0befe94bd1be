"""``qsls fly``: controllers flown in the simulated closed loop, and the paper's findings tested
paired by seed (docs/evaluation.md)."""
