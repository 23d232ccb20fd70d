"""Tables and figures of the paper, regenerated from the MLflow store alone, or (the tables)
from evaluation records (`analysis.records`: small files a store's runs were exported to).

Everything here reads MLflow (runs, metrics, artifacts) or those records and never Hydra's
output folders, so a figure can be remade from the store on any machine. Each module is a
command, e.g. `python -m analysis.curves` (run from the project root).
"""
