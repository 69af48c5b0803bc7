"""Inspector's front ends: the command line, the operator's GUI, the OPC UA server and the Dask client.

Each drives the Qt-free core (:class:`inspector.session.Session`, :mod:`inspector.runner`);
none is imported by the core, the plugins or the drivers (import-linter's layer contract).
"""
