"""Finished runs: the run directory's format (`rundir`), the paper's statistics and report
(`report`) and every figure (`figures`). Nothing here imports JAX, Brax, QDax or Flax at
import time, so reading and reporting on runs does not load them."""
