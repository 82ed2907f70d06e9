"""What keeps one client from taking the service from the others (docs/hardening.md).

``connections`` (every open connection counted, idle ones give way), ``protocol`` and
``ws_protocol`` (uvicorn's HTTP and WebSocket protocols with the limits they lack),
``byte_budget`` (request bytes held, bounded), ``body`` (one body read under those limits),
``parse_pool`` and ``parse_worker`` (large JSON bodies parsed in worker processes).
"""
