"""The operator GUI (``inspector gui``): PySide6 widgets and a pyvistaqt 3D view over one
:class:`inspector.session.Session`.

Only this package imports Qt, pyvista or VTK; the core, the CLI and the plugins never do
(``tests/core/test_manager.py`` checks it in a subprocess). Importing this package itself
imports nothing heavy: :mod:`inspector_frontends.gui.app` does, when the GUI starts.

Modules: ``viewmodel`` (Qt-free: what the screen shows, built from an inspection or a
result folder), ``worker`` (the session in a worker thread, events as queued signals),
``widgets`` (banner, defect table, camera strip, history strip), ``view3d`` (the 3D view),
``editor`` (the engineer's recipe form), ``window`` (the operator screen: fitted to its
screen, kiosk mode, the shift panel), ``app`` (the command, ``--kiosk``, ``--lang``,
``--config``), ``i18n`` (the German and Spanish translations, Qt's ``.ts``/``.qm`` files and
``python -m inspector_frontends.gui.i18n.build``).
"""
