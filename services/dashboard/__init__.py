"""The dashboard served at ``/`` (static assets in ``static/``) and the 3-D scene Foxglove shows of an execution."""
