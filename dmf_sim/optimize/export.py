"""A design as a driveline YAML: the study's base driveline file with the design's DMF (its
primary stiffness and damping on the DMF element, its drive and coast stages), ready for
``--config`` of the commands and for the node's ``driveline`` parameter."""
from __future__ import annotations

from pathlib import Path

import yaml

from dmf_sim.design.parameters import design_driveline

__all__ = ['design_yaml', 'write_designs']


def design_yaml(problem, row: dict) -> str:
    """The driveline YAML text of a design's summary row (validated by loading it back)."""
    from dmf_sim.core.paths import parse_yaml, read_yaml_mapping
    from dmf_sim.design.evaluate import StudyContext
    from dmf_sim.physics.model import driveline_from_dict
    study = problem.study
    ctx = StudyContext.from_study(study)
    line = design_driveline(study.base, ctx.design_values([row[v] for v in study.variable_names]))
    _, data = read_yaml_mapping(study.driveline, 'driveline')
    el = line.dmf_element
    for raw in data['elements']:
        if raw['name'] == el.name:
            raw['stiffness'] = float(el.stiffness)
            raw['damping'] = float(el.damping)
    spring = line.spring
    data['name'] = f'{study.name}_design_{row["design_id"]}'
    data['description'] = (f'{study.name}: design {row["design_id"]} of dmf-sim optimize '
                            f'(base {study.base.name}); ' + ', '.join(
                                f'{o} = {row[o]:.5g}' for o in study.objectives
                                if row.get(o) is not None))
    data['dmf'] = {'element': line.dmf.element,
                   'stages': [{'angle_rad': float(s.angle_rad),
                               'stiffness_factor': float(s.stiffness_factor)}
                              for s in spring.drive],
                   'coast_stages': [{'angle_rad': float(s.angle_rad),
                                     'stiffness_factor': float(s.stiffness_factor)}
                                    for s in spring.coast]}
    if not data['dmf']['coast_stages']:
        del data['dmf']['coast_stages']
    text = (f'# {data["description"]}\n# written by dmf-sim optimize; use with --config or the '
            "node's driveline parameter\n" + yaml.safe_dump(data, sort_keys=False, width=99))
    driveline_from_dict(parse_yaml(text, data['name']), data['name'])      # it loads back
    return text


def write_designs(problem, rows: list[dict], out) -> dict[str, str]:
    """``out/designs/design_<id>.yaml`` for every row; returns id -> path. The directory holds
    these designs only: files of an earlier run's designs that are no longer among ``rows``
    (a resumed run's front moved) are removed, so none is taken for a current design."""
    d = Path(out) / 'designs'
    d.mkdir(parents=True, exist_ok=True)
    files = {}
    for r in rows:
        path = d / f'design_{r["design_id"]}.yaml'
        path.write_text(design_yaml(problem, r))
        files[str(r['design_id'])] = str(path)
    for old in d.glob('design_*.yaml'):
        if str(old) not in files.values():
            old.unlink()
    return files
