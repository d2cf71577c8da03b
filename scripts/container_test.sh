#!/usr/bin/env bash
# Build the service image, start it with settings in DEFORM_* variables (a bearer token, JSON access log),
# wait for its HEALTHCHECK endpoint, POST /predict without and with the token, stop it.
set -euo pipefail
IMAGE=${1:-deform-service}
PORT=${PORT:-18000}
ENGINE=$(command -v podman || command -v docker || true)
[ -n "$ENGINE" ] || { echo "no podman or docker; run ../shared/container/setup-podman.sh first" >&2; exit 2; }

# podman writes OCI images by default, which drop HEALTHCHECK; the docker format keeps it.
format=(); [[ "$ENGINE" == *podman ]] && format=(--format docker)
"$ENGINE" build "${format[@]}" --network=host -t "$IMAGE" .
name="deform-test-$$"
TOKEN=container-test-token
"$ENGINE" run -d --rm --name "$name" --network=host -e DEFORM_PORT="$PORT" -e DEFORM_AUTH_TOKENS="$TOKEN" \
  -e DEFORM_ACCESS_LOG=json "$IMAGE" >/dev/null
trap '"$ENGINE" stop -t 2 "$name" >/dev/null 2>&1 || true' EXIT

for _ in $(seq 60); do
  curl -fsS "http://127.0.0.1:$PORT/readyz" >/dev/null 2>&1 && break
  sleep 1
done
curl -fsS "http://127.0.0.1:$PORT/readyz"; echo
status=$(curl -s -o /dev/null -w '%{http_code}' -X POST "http://127.0.0.1:$PORT/predict" -H 'content-type: application/json' -d '{"displacement_mm": 5, "angle_deg": 2}')
[ "$status" = 401 ] || { echo "a request without the token got $status, expected 401 (DEFORM_AUTH_TOKENS not read?)" >&2; exit 1; }
reply=$(curl -fsS -X POST "http://127.0.0.1:$PORT/predict" -H "authorization: Bearer $TOKEN" -H 'content-type: application/json' \
  -d '{"displacement_mm": 5, "angle_deg": 2, "region": "markers"}')
echo "$reply" | python3 -c "import json, sys; r = json.load(sys.stdin); assert r['count'] == 8, r; print('POST /predict markers:', r['count'], 'positions, first', r['positions'][0])"
status=$(curl -s -o /dev/null -w '%{http_code}' -X POST "http://127.0.0.1:$PORT/predict" -H "authorization: Bearer $TOKEN" -H 'content-type: application/json' -d '{"displacement_mm": 50, "angle_deg": 0}')
[ "$status" = 422 ] || { echo "out-of-envelope request got $status, expected 422" >&2; exit 1; }
"$ENGINE" image inspect "$IMAGE" | grep -q service.healthcheck || { echo "image has no HEALTHCHECK" >&2; exit 1; }
"$ENGINE" logs "$name" 2>/dev/null | grep -q '"path":"/predict","status":401' || { echo "no JSON access log line for the 401" >&2; exit 1; }
if [[ "$ENGINE" == *podman ]]; then podman healthcheck run "$name" && echo "HEALTHCHECK: healthy"; fi
user=$("$ENGINE" exec "$name" id -u)
[ "$user" != 0 ] || { echo "container runs as root" >&2; exit 1; }
"$ENGINE" exec "$name" python -c "import importlib.util as u, sys; bad = [m for m in ('torch', 'gmsh', 'skfem', 'fem_offline', 'training') if u.find_spec(m)]; sys.exit(f'image holds {bad}' if bad else 0)"
echo "container test passed: image $IMAGE, uid $user, no torch/gmsh/scikit-fem/FE code"
