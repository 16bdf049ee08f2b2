# nscatter service image: Debian 12 (bookworm-slim), multi-stage.
#
#   docker build -t nscatter .
#   docker run --rm -p 127.0.0.1:8080:8080 nscatter      # web page at http://127.0.0.1:8080/
#
# The build stage uses the same scripts/setup.sh as the README, so the image is built the
# way a developer builds; the runtime stage holds only the binary, the example scenes and
# the shared libraries it links, and renders on Mesa's lavapipe (CPU Vulkan) by default.
#
#   docker build --target test .     # the HTTP and CLI integration tests, in the image
#
# The runtime stage is the last one, so it stays the default target. See docs/container.md.

# ---------------------------------------------------------------------------------------
# build: compilers, headers, glslang; produces /src/build/nscatter
# ---------------------------------------------------------------------------------------
FROM debian:bookworm-slim AS build
WORKDIR /src
# Packages first, from the setup script alone, so this layer is reused until it changes.
COPY scripts/setup.sh scripts/setup.sh
RUN scripts/setup.sh deps && rm -rf /var/lib/apt/lists/*
COPY . .
RUN scripts/setup.sh build

# ---------------------------------------------------------------------------------------
# test: the HTTP and CLI integration tests (ctest -L 'http|cli') against /src/build/nscatter,
# the very file the runtime stage copies. Built only on request (--target test); any failed
# test fails the build.
# ---------------------------------------------------------------------------------------
# From the build stage, not the runtime one: the tests need the source tree (the test
# programs, scenes/, deploy/, the headers and sources some of them read) and CTest's files,
# which name /src/build; the build stage has both, and its libraries are the same Debian
# packages' (the runtime stage checks its own with ldd and `nscatter info`).
FROM build AS test
# The HTTP tests' packages (python3 and its prometheus-client, jsonschema and yaml modules,
# nginx-light for http_scaleout) and Node.js with web/'s npm packages, whose OpenAPI validator
# http_openapi runs: `npm ci` needs the npm registry (registry.npmjs.org) during the build.
# No Chromium and no validation layers: the browser and GPU tests are not run here.
RUN scripts/setup.sh http-test-deps && rm -rf /var/lib/apt/lists/* /root/.npm
# CMake looks for python3 again (the build stage may have configured without it); this
# rewrites CTest's files only and rebuilds nothing.
RUN cmake -S . -B build >/dev/null
# As the runtime stage's user (uid 10001, its home for Mesa's shader cache), owning only what
# the tests write: CTest's log and the tests' table cache in build/. Temporary files go to
# /tmp.
RUN useradd --system --user-group --uid 10001 --home-dir /var/lib/nscatter --create-home \
      --shell /usr/sbin/nologin nscatter \
 && chown -R nscatter:nscatter build
USER nscatter
# --no-tests=error: a test list that matched nothing (a missing python3 at configure time)
# fails rather than passing empty.
RUN cd build && ctest -L 'http|cli' --output-on-failure --no-tests=error --timeout 900

# ---------------------------------------------------------------------------------------
# runtime: shared libraries only, non-root
# ---------------------------------------------------------------------------------------
FROM debian:bookworm-slim AS runtime
# The runtime halves of the -dev packages whose libraries the binary links (apt-cache
# depends libtinyexr-dev -> libtinyexr1d, libmicrohttpd-dev -> libmicrohttpd12, ...).
# libopenblas0 is for `nscatter train`, which lives in the same binary. tinygltf,
# nlohmann-json and stb are compiled in, so libstb0 is not needed; the ldd check below
# fails the build if a linked library is ever missing from this list. mesa-vulkan-drivers
# brings lavapipe and its ICD file. curl is only for the HEALTHCHECK: slim images have no
# HTTP client.
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libvulkan1 mesa-vulkan-drivers \
      libmicrohttpd12 libjansson4 libtinyexr1d zlib1g libopenblas0 libstdc++6 \
      curl \
 && rm -rf /var/lib/apt/lists/*

COPY --from=build /src/build/nscatter /usr/local/bin/nscatter
COPY --from=build /src/scenes /usr/share/nscatter/scenes

# Fail the image build, not the first request, if a library is missing or Vulkan cannot
# find a device.
RUN if ldd /usr/local/bin/nscatter | grep 'not found'; then exit 1; fi \
 && nscatter --version \
 && nscatter info

# An unprivileged system user; its home takes Mesa's shader cache.
RUN useradd --system --user-group --uid 10001 --home-dir /var/lib/nscatter --create-home \
      --shell /usr/sbin/nologin nscatter
USER nscatter
WORKDIR /var/lib/nscatter

EXPOSE 8080
# Liveness, not readiness: /readyz answers 503 without a render device and once a stop
# signal came (draining), and a draining service is not an unhealthy one. Load balancers
# poll /readyz themselves (deploy/nginx.conf retries a 503 elsewhere; deploy/k8s).
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
  CMD curl -fsS -o /dev/null http://127.0.0.1:8080/livez || exit 1
# --assets: the meshes that scenes/*.json name ("asset": "octahedron.glb").
CMD ["nscatter", "serve", "--host", "0.0.0.0", "--port", "8080", "--assets", "/usr/share/nscatter/scenes/assets"]
