"""`ccf study`: the paper's experiments on recorded and simulated data, with a verdict per claim."""

__all__ = [
    'bode',
    'datasets',
    'experiments',
    'figures',
    'labels',
    'lscf',
    'means',
    'report',
    'run',
    'tables',
    'verdicts',
]
