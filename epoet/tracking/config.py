"""The tracking config group's schema (conf/tracking/): where runs are recorded."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from epoet.core.schema import check


@dataclass
class TrackingConfig:
    """MLflow: the store defaults to sqlite:///<the folder the command started in>/mlflow.db;
    MLFLOW_TRACKING_URI wins."""

    KEY: ClassVar[str] = "tracking"

    experiment: str
    uri: Optional[str]

    def __post_init__(self) -> None:
        check(bool(self.experiment), "tracking.experiment must not be empty.")
