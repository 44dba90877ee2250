"""Re-creations of the paper's case studies and an evaluation on recorded traffic, end to end.

Nakamura & Bansal, "Online Update of Safety Assurances Using Confidence-Based Predictions",
section "Case Studies": a U-turn and a car running its stop sign, each with and without model
confidence, and the effects of beta_low and gamma. Everything here drives the real service over
HTTP through the client SDK; nothing imports the service's internals.

Modules, one idea each:

- :mod:`experiments.scenes`: the two scenes (lanes, stop lines) and the human's true trajectory;
- :mod:`experiments.predictor`: the confidently wrong stand-in for Trajectron++;
- :mod:`experiments.planner`: the paper's ego planner (constant speed, stop or brake maximally);
- :mod:`experiments.server`: the service as a uvicorn subprocess and the SDK client to it;
- :mod:`experiments.run_scenarios`: the closed loop, with confidence on and off;
- :mod:`experiments.sweeps`: beta over time for several beta_low, the FRT for several gamma;
- :mod:`experiments.av2`: replay of Argoverse 2 tracks, coverage of K and C, area of C;
- :mod:`experiments.plots`: the figures;
- :mod:`experiments.run_all`: ``python -m experiments.run_all`` (``make scenarios``).
"""
