"""The REST API, one module per concern: ``main`` (the router of routers), ``routes/`` (one APIRouter per
resource), ``deps`` (store, settings, bus, token guard as ``Annotated`` dependencies), ``errors`` (every error
answer), ``body_limit`` (413), ``limits`` and ``responses``. The app itself is built by ``services.app.create_app``.
"""
