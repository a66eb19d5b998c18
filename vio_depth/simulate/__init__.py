"""Deterministic SIMULATED sample sequences: textured ray-cast scenes, smooth trajectories and
consistent IMU samples (the SIMULATED disparity model itself is :mod:`vio_depth.disparity.simulation`).

Submodules: :mod:`.textures` (mip-mapped skimage photos), :mod:`.scenes` (quads, boxes,
street / room scenes), :mod:`.render` (numpy ray casting: RGB + exact depth),
:mod:`.trajectory` (analytic body trajectories), :mod:`.imu` (IMU simulation and a
reference integrator), :mod:`.generate` (the bundled samples; ``python -m vio_depth.simulate
--out DIR``). Nothing here is needed to read a sequence; the textures need scikit-image
(``pip install -e '.[dev]'``).
"""
