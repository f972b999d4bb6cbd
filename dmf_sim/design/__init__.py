"""DMF design studies: many designs x operating conditions, evaluated on Dask.

``run_study(study, client=None) -> StudyResult`` from Python or a notebook; ``dmf-sim design
STUDY.yaml --out DIR`` from the command line. Modules:

* ``study``: the study file (schema, one-line validation), ``parameters``: DMF parameters by
  name -> the design's driveline, ``sampling``: grid / random / Latin hypercube;
* ``evaluate``: one design over its conditions (``solve_condition`` is the one place that picks
  the steady-state solver), ``states``: steady states on the speed grid and the torque at an
  element, ``metrics``: what is reported per design and condition;
* ``table``: the tidy table and its resumable store, ``pareto``, ``result``: StudyResult,
  ``runner``: Dask (LocalCluster or an existing scheduler), ``plots``.
"""
from dmf_sim.design.result import StudyResult
from dmf_sim.design.runner import run_study
from dmf_sim.design.study import Study, read_study

__all__ = ['run_study', 'StudyResult', 'Study', 'read_study']
