# nscatter service image: Debian 12 (bookworm-slim), multi-stage.
#
#   docker build -t nscatter .
#   docker run --rm -p 127.0.0.1:8080:8080 nscatter      # web page at http://127.0.0.1:8080/
#
# The build stage uses the same scripts/setup.sh as the README, so the image is built the
# way a developer builds; the runtime stage holds only the binary, the example scenes and
# the shared libraries it links, and renders on Mesa's lavapipe (CPU Vulkan) by default.
# See docs/container.md.

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
