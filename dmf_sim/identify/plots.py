"""The plot of an identification: measured against fitted signal (``identify.png``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dmf_sim.identify.fit import Identification

__all__ = ['plot_identification']


def plot_identification(result: Identification, t_s: np.ndarray, measured: np.ndarray,
                        fitted: np.ndarray, initial: np.ndarray, path: Path) -> Path:
    """Measured, fitted and starting-value signal over time, the residual below; the fitted
    values and their relative standard deviations in the title."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True,
                                      gridspec_kw={'height_ratios': [3, 1]})
    label = 'wind-up [rad]' if result.signal == 'windup' else 'relative speed [rad/s]'
    top.plot(t_s, measured, color='0.55', lw=0.8, label='measured')
    top.plot(t_s, initial, color='tab:orange', lw=0.8, ls='--',
             label=f'starting values (rms {result.rms_initial:.3g} {result.unit})')
    top.plot(t_s, fitted, color='tab:blue', lw=0.9,
             label=f'fitted (rms {result.rms:.3g} {result.unit})')
    top.set_ylabel(label)
    top.legend(loc='best', fontsize=8)
    bottom.plot(t_s, measured - fitted, color='tab:blue', lw=0.6)
    bottom.set_ylabel(f'residual [{result.unit}]')
    bottom.set_xlabel('time [s]')
    text = ', '.join(f'{n} = {v:.4g} (±{100 * result.rel_std[n]:.2g} %)'
                     for n, v in result.values.items())
    top.set_title(f'{Path(result.bag).name}: {text}', fontsize=9, wrap=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
