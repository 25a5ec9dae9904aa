# Contact Skills: one image for the REST API (`contact-skills api`) and the sim workers (`contact-skills worker`).
# The Zenoh router is the official eclipse/zenoh image (see docker-compose.yml).

# ---- build: wheels of the project and its dependencies (a compiler for those without a wheel, e.g. pybullet)
FROM python:3.11-slim AS build
RUN apt-get update \
    && apt-get install -y --no-install-recommends build-essential \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY pyproject.toml README.md ./
COPY schemas/ schemas/
COPY skills/ skills/
COPY corpus/ corpus/
COPY execution/ execution/
COPY services/ services/
COPY sim_worker/ sim_worker/
COPY sim_mujoco/ sim_mujoco/
COPY experiments/ experiments/
COPY cli/ cli/
RUN pip wheel --no-cache-dir --wheel-dir /wheels ".[service]"

# ---- runtime: no compiler, the project installed from the wheels
FROM python:3.11-slim
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    OMP_NUM_THREADS=1 \
    OPENBLAS_NUM_THREADS=1 \
    MPLBACKEND=Agg
COPY --from=build /wheels /wheels
RUN pip install --no-cache-dir --no-index --find-links /wheels "contact-skills[service]" \
    && rm -rf /wheels \
    && contact-skills --help > /dev/null

# The API's database goes to /data, the bus logins to /keys and /worker-logins, where docker-compose mounts the named
# volumes (a fresh named volume takes the owner of the folder it is mounted on: the runtime user's). No VOLUME here:
# it would give every container, each worker too, an anonymous volume. The API listens on all interfaces INSIDE the
# container only (docker-compose publishes it on the host's loopback).
RUN useradd --create-home --uid 1000 cskills \
    && mkdir -p /data /keys /worker-logins \
    && chown cskills /data /keys /worker-logins
USER cskills
WORKDIR /home/cskills
# The compiled control loop is cached where the runtime user can read and write it, and warmed up AS that user:
# every container starts with it compiled (as root, the cache went where the user could not write, and every
# container compiled it again: 17 s).
ENV NUMBA_CACHE_DIR=/home/cskills/.cache/numba
RUN contact-skills warm-up
ENV CONTACT_SKILLS_DB=/data/contact_skills.db
EXPOSE 8000 8765

ENTRYPOINT ["contact-skills"]
CMD ["api", "--host", "0.0.0.0"]
