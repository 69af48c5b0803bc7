"""The operator GUI (``inspector gui``): PySide6 widgets and a pyvistaqt 3D view over one
:class:`inspector.session.Session`.

Only this package imports Qt, pyvista or VTK; the core, the CLI and the plugins never do
(``tests/core/test_manager.py`` checks it in a subprocess). Importing this package itself
imports nothing heavy: :mod:`inspector_frontends.gui.app` does, when the GUI starts.

Modules: ``viewmodel`` (Qt-free: what the screen shows, built from an inspection or a
result folder), ``worker`` (the session in a worker thread, events as queued signals),
``widgets`` (verdict banner, defect table), ``cameras`` (camera strip, large camera view),
``history_strip`` (history strip, shift panel), ``prepare`` (the drawing made ahead in the
worker thread), ``view3d`` (the 3D view), ``editor`` (the engineer's recipe form), ``screen``
(the window fitted to its screen, the kiosk's return to the front), ``window`` (the operator
screen), ``collector`` (the garbage collector on the GUI thread), ``app`` (the command,
``--kiosk``, ``--lang``,
``--config``), ``i18n`` (the German and Spanish translations, Qt's ``.ts``/``.qm`` files and
``python -m inspector_frontends.gui.i18n.build``).
"""
