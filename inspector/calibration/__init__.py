"""Commissioning the cell (built-in plugin ``calibrate``, a tool): calibration targets
(:mod:`.target`), ``inspector calibrate`` (:mod:`.command`): calibrate from a ChArUco target
(:mod:`.solve`), verify with a gauge (:mod:`.gauge`), refine from the parts' silhouettes
(:mod:`.refine`)."""
