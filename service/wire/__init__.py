"""The wire contract, below every other package of ``service/``: the request and response models
(``schemas``), the one tree of errors with their HTTP status and JSON shape (``errors``, no web
framework in it) and the configurable request limits (``limits``).

``service.api`` (routes, handlers) -> ``service.flows`` (the engine of each request) ->
``service.runtime`` (settings, stores, scheduler, metrics) -> ``service.wire``: every arrow runs
this way (``tests/test_layering.py``).
"""
