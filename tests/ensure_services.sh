#!/usr/bin/env bash
# Make sure the PostgreSQL and Redis servers the tests use are up; start them if they are
# installed but stopped; fail loudly otherwise. Tests never skip for a missing server.
set -uo pipefail
database_url=${1:?database url}
redis_url=${2:?redis url}

pg_up() { pg_isready -q -h 127.0.0.1 -p 5432; }
redis_up() { redis-cli -u "$redis_url" ping 2>/dev/null | grep -q PONG; }

if ! pg_up; then
  echo "PostgreSQL is not answering on 127.0.0.1:5432; starting it"
  if command -v pg_ctlcluster >/dev/null && [ -d /etc/postgresql ]; then
    pg_ctlcluster --skip-systemctl-redirect "$(ls /etc/postgresql | sort -V | tail -1)" main start || true
  fi
  for _ in $(seq 30); do pg_up && break; sleep 1; done
  pg_up || { echo "ERROR: PostgreSQL is not running and could not be started (tests need it)" >&2; exit 1; }
fi

if ! redis_up; then
  echo "Redis is not answering at $redis_url; starting it"
  if command -v redis-server >/dev/null; then
    mkdir -p /var/lib/redis /var/log/redis
    redis-server --daemonize yes --bind 127.0.0.1 -::1 --port 6379 --save "" --appendonly no \
      --dir /var/lib/redis --logfile /var/log/redis/ci.log || true
  fi
  for _ in $(seq 30); do redis_up && break; sleep 1; done
  redis_up || { echo "ERROR: Redis is not running and could not be started (tests need it)" >&2; exit 1; }
fi

echo "services: PostgreSQL $(psql "$database_url" -XAtc 'show server_version' 2>/dev/null || psql -h 127.0.0.1 -U postgres -XAtc 'show server_version' postgres) and Redis $(redis-cli -u "$redis_url" info server | sed -n 's/^redis_version:\(.*\)\r$/\1/p') are up"
