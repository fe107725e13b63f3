"""The application workloads: one folder per application, named as its kind.

``workloads/apps/<name>/`` holds the application's TOML files and meshes and
its code in one module, the folder's ``__init__.py``, which defines
``WORKLOAD``, a :class:`pipeline_sim.workload.Workload` subclass. A file with
``kind = "<name>"`` runs it (docs/workloads.md).
"""
