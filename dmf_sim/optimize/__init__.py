"""Designing the DMF spring: multi-objective, robust, constrained optimization on Dask.

``run_optimization(problem, client=None) -> OptimizationResult`` from Python; ``dmf-sim optimize
STUDY.yaml --out DIR`` from the command line. A layer beside ``dmf_sim.design``, built on it:

* ``problem``: the study file's ``optimizer`` section, variables (stage angles as increments);
* ``constraints``: torque capacity before the travel, DMF torque in operation, metric bounds;
* ``runner``: optuna (NSGA-II, TPE; LHS/random baselines) ask-and-tell on Dask, journal storage
  (resume), every design a row of the design study's table;
* ``hypervolume``, ``verify`` (Newmark run-ups and shots of the Pareto designs), ``export``
  (driveline YAML per design), ``report`` (figures, Markdown + HTML).
"""
from dmf_sim.optimize.problem import Problem, read_problem
from dmf_sim.optimize.runner import OptimizationResult, run_optimization

__all__ = ['run_optimization', 'OptimizationResult', 'Problem', 'read_problem']
