"""Deterministic SIMULATED sample sequences: textured ray-cast scenes, smooth trajectories,
consistent IMU samples and a SIMULATED affine-invariant disparity model.

Submodules: :mod:`.textures` (mip-mapped skimage photos), :mod:`.scenes` (quads, boxes,
street / room scenes), :mod:`.render` (numpy ray casting: RGB + exact depth),
:mod:`.trajectory` (analytic body trajectories), :mod:`.imu` (IMU simulation and a
reference integrator), :mod:`.disparity` (SIMULATED disparity used at load time),
:mod:`.generate` (the bundled samples; ``python -m vio_depth.simulate --out DIR``).

Only :mod:`.disparity` is needed at load time; the others need scikit-image
(``pip install -e '.[dev]'``) for the textures.
"""
