"""The REST service, persistence and the Zenoh client side."""
