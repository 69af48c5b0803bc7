"""Measured characteristics (issue 28): from a deviation map to a gauge's list of values.

* :mod:`inspector.kernels.features` finds the reference's geometric features (planes,
  cylinders, cones, spheres, tori) and :mod:`inspector.kernels.fits` fits them with their
  uncertainty;
* :mod:`.measure`: the characteristics a recipe defines (:class:`~.measure.Characteristic`),
  checked against the features, and measured from one inspection's BCPS points
  (:func:`~.measure.measure`): value, deviation, ``u`` and ``U = 2u``, verdict
  ``ok``/``nok``/``not_measurable`` with the reason;
* :mod:`.formats`: the quality-data formats plants require: Q-DAS AQDEF (DFQ) and QIF 3.0
  Results;
* :mod:`.features_cmd`: ``inspector features REFERENCE`` (built-in plugin ``features``).

A built-in plugin and its library, not the core: importing this package is cheap.
"""
