"""``qsls run CONFIG``: the pipeline from one YAML file as a cached stage graph."""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "RunConfig": "runner",
        "load_run_config": "runner",
        "run": "runner",
        "StageGraph": "graph",
        "build_graph": "stages",
        "resolve_sections": "sections",
    },
)
