#!/usr/bin/env bash
# A target lost on the way is no verdict: `props`, `fuzz`, `replay` and `run`
# against `mbconform serve` killed (SIGKILL) while they run say INCOMPLETE and
# exit 2, never "falsified" or a finding with exit 1 (the case `run` lost it in
# is still a FAIL in its report). Usage: lost_target_test.sh MBCONFORM OUTDIR
set -euo pipefail
mbc=$1 out=$2
rm -rf "$out" && mkdir -p "$out"
pids=()
trap 'for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; wait "$p" 2>/dev/null || true; done' EXIT

serve() {  # starts serve on a fresh port; sets $port and $spid
  : > "$out/serve.out"
  "$mbc" serve --device hsc60@1 --rtu-tcp 127.0.0.1:0 > "$out/serve.out" 2> "$out/serve.err" &
  spid=$!
  pids+=($spid)
  for _ in $(seq 100); do grep -q '^listening rtu-tcp' "$out/serve.out" && break; sleep 0.1; done
  port=$(sed -n 's/^listening rtu-tcp .*:\([0-9]*\).*/\1/p' "$out/serve.out" | head -1)
  [ -n "$port" ] || { echo "serve did not start"; cat "$out/serve.out" "$out/serve.err"; exit 1; }
}

connected() {  # an established TCP connection to serve's $port (/proc/net/tcp: local address, state 01)
  awk -v p="$(printf ':%04X' "$port")" '$4 == "01" && substr($2, length($2) - 4) == p { found = 1 } END { exit !found }' /proc/net/tcp
}

# COMMAND... run in the background; serve is killed SECONDS after the command
# connected to it (when $port is set; a slow host, e.g. under ASan, may take
# seconds to connect), or after SECONDS; the command must end with exit 2 and say INCOMPLETE.
lost() {  # lost NAME SECONDS COMMAND...
  local name=$1 after=$2
  shift 2
  "$@" > "$out/$name.log" 2>&1 &
  local cpid=$!
  if [ -n "$port" ]; then
    for _ in $(seq 600); do connected && break; sleep 0.1; done
    connected || { echo "$name: never connected to serve"; cat "$out/$name.log"; exit 1; }
  fi
  sleep "$after"
  kill -9 "$spid"
  set +e
  wait "$cpid"
  local rc=$?
  set -e
  cat "$out/$name.log"
  [ "$rc" -eq 2 ] || { echo "$name: exit $rc with the target lost, expected 2"; exit 1; }
  grep -q 'INCOMPLETE' "$out/$name.log" || { echo "$name: no INCOMPLETE line"; exit 1; }
  ! grep -q 'falsified' "$out/$name.log" || { echo "$name: a lost target called falsified"; exit 1; }
}

serve
lost props 2 "$mbc" props --target "rtu-tcp://127.0.0.1:$port?unit=1" --device hsc60 --only read-after-write \
  --cases 100000 --seed 3 --out "$out/props" -q
serve
lost fuzz 2 "$mbc" fuzz --target "rtu-tcp://127.0.0.1:$port?unit=1" --device hsc60 --duration 30s --seed 3 \
  --out "$out/fuzz" -q
serve
cat > "$out/script.txt" <<'SCRIPT'
mbconform-script 2
rtu 01 03 00 00 00 01 84 0A  -> normal
wait 3000
rtu 01 03 00 00 00 01 84 0A  -> normal
SCRIPT
lost replay 1 "$mbc" replay "$out/script.txt" --target "rtu-tcp://127.0.0.1:$port?unit=1" --device hsc60 --out "$out/replay" -q
# `run` on a serial line (a pty at 9600 baud: slow enough to be cut off).
port=""
"$mbc" serve --device hsc60@1 --pty "$out/line" --baud 9600 --line-rate 9600 > "$out/serve.out" 2> "$out/serve.err" &
spid=$!
pids+=($spid)
for _ in $(seq 100); do grep -q '^listening pty' "$out/serve.out" && break; sleep 0.1; done
lost run 3 "$mbc" run --target "rtu://$out/line?baud=9600&parity=N&unit=1" --device hsc60 --out "$out/run" -q
echo "a lost target is INCOMPLETE (exit 2) in props, fuzz, replay and run"
