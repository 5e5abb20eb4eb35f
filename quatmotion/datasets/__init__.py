"""The motion-capture data folder: where it is, what clips it holds, fetching more.

See :mod:`quatmotion.datasets.catalogue` for the folder's location and layouts and
:mod:`quatmotion.datasets.fetch` for downloading CMU subjects.
"""

from quatmotion.datasets.catalogue import (
    CMU_INDEX_RELPATH,
    COLLECTIONS,
    DATA_ENV_VAR,
    ClipEntry,
    DataNotFoundError,
    catalogue,
    cmu_index,
    data_root,
    project_root,
)
from quatmotion.datasets.fetch import (
    DEFAULT_CMU_BASE_URL,
    FetchError,
    cmu_trials,
    cmu_url,
    fetch_cmu,
)

__all__ = [
    "CMU_INDEX_RELPATH",
    "COLLECTIONS",
    "DATA_ENV_VAR",
    "DEFAULT_CMU_BASE_URL",
    "ClipEntry",
    "DataNotFoundError",
    "FetchError",
    "catalogue",
    "cmu_index",
    "cmu_trials",
    "cmu_url",
    "data_root",
    "fetch_cmu",
    "project_root",
]
