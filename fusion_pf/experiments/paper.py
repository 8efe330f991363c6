"""The experiment sizes of paper 003 (imported by the command line without loading the pipeline)."""

#: Particle counts of paper 003 §4.4.
PAPER_PARTICLE_COUNTS = (5, 10, 25, 50, 75, 100, 125, 150, 200, 250)

#: Runs per particle count of paper 003 §4.5.
PAPER_RUNS = 20
