"""Beyond one machine, on Ray (the ``itnet[ray]`` extra): the service as a Ray Serve application
(``serve_app``) and poses of whole collections of clouds on Ray Data (``batch``).

Nothing here is imported by ``itnet.service`` or by ``itnet --help``: Ray loads only when one of
these is used.
"""
