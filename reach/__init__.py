"""The certified geometry of the forward reachable tube: what the service guarantees.

Every set the service serves for a setting (v_start and the eight control bounds of the extended
unicycle, ``reach.contract``, ``reach.dynamics``) holds every position any admissible trajectory
reaches, by construction:

* ``outer_bound``: interval propagation of the dynamics gives, per 0.025 s sweep, a box and a
  support vector in 16 directions that nothing reachable leaves (``polygons`` turns support
  vectors into convex polygons);
* ``corridors``, ``speed_programme``, ``partition``: trajectories binned by their final heading
  (and headings at waypoints) each keep to a heading corridor and a speed profile of bounded rate;
  the union of the bins' polygons keeps the notch behind a car that can turn round
  (``notch``: where and in which stages the service cuts its sets to it);
* ``sets``, ``field_tube``, ``field_stack``, ``refine``: the sets themselves (slices, intervals,
  tubes), drawn on one lattice from the outer polygons and, where a ``value_field`` is plugged in,
  cut by it inside them; ``engine`` builds them;
* ``frames``, ``distances``, ``geojson``: the human frame, signed distances (clearances) and the
  contours answered.

No torch, no onnxruntime, no FastAPI: ``models`` and ``service`` import this package, never the
other way round (tests/test_layering.py).
"""
