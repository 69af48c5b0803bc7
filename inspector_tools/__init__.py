"""Inspector's tools: benchmarks, experiments, the feasibility study, the Numba precompile step,
the plugin author's kit (scaffold, reference, pytest fixtures), dataset importers and camera emulators.

Tools stand on top: they may use the core, the plugins, the drivers and the front ends; nothing in
the product imports a tool (import-linter's layer contract).
"""
