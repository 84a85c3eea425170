"""Settings for the AMazING portal, read from the environment at start.

Every variable is documented in README.md ("Configuration"). With no environment at all the
portal runs in the embedded mode that ``make run`` uses: SQLite and a Celery transport that
needs no server. Production (``DJANGO_DEBUG`` false) refuses to start without a secret key,
allowed hosts and the agent token.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import environ
from csp import constants as csp_constants
from django.core.exceptions import ImproperlyConfigured

from bookings.scheduler import config as scheduler_config
from core.logs import logging_config
from portal import conf
from portal.processes import MAIL_QUEUE, RUNS_QUEUE

BASE_DIR = Path(__file__).resolve().parent.parent
VAR_DIR = Path(environ.Env().str("AMAZING_VAR_DIR", default=str(BASE_DIR / "var")))

env = environ.Env()


def env_secret(name: str, default: str | None = None) -> str | None:
    """A secret from ``NAME`` or from the file named by ``NAME_FILE`` (Docker/systemd secrets),
    as given: read from the environment itself, since django-environ takes a value starting
    with ``$`` for the name of another variable (and Django's own keys may start so)."""
    value = os.environ.get(name)
    if value:
        return value
    path = env.str(f"{name}_FILE", default=None)
    if path:
        try:
            return Path(path).read_text().strip()
        except OSError as exc:
            raise ImproperlyConfigured(f"{name}_FILE={path} cannot be read: {exc}") from exc
    return default


DEBUG = env.bool("DJANGO_DEBUG", default=False)

_secret_key = env_secret("DJANGO_SECRET_KEY")
if _secret_key is None:
    if not DEBUG:
        raise ImproperlyConfigured(
            "DJANGO_SECRET_KEY (or DJANGO_SECRET_KEY_FILE) is required when DJANGO_DEBUG is off"
        )
    # Development only: a per-checkout key, never a shared default.
    _key_file = VAR_DIR / "dev-secret-key"
    if not _key_file.exists():
        from django.core.management.utils import get_random_secret_key

        # Processes starting together must agree on one key: each writes its own whole file
        # and links it into place; a link fails if another was first, whose key is then read.
        _key_file.parent.mkdir(parents=True, exist_ok=True)
        _mine = _key_file.with_name(f".{_key_file.name}.{os.getpid()}")
        _mine.write_text(get_random_secret_key())
        _mine.chmod(0o600)
        try:
            os.link(_mine, _key_file)
        except FileExistsError:
            pass
        finally:
            _mine.unlink()
    _secret_key = _key_file.read_text().strip()
SECRET_KEY: str = _secret_key
# Earlier secret keys, still accepted for signatures and for reading the agent tokens stored
# under them (bookings/agent_tokens.py), while a new key takes over.
_fallbacks = os.environ.get("DJANGO_SECRET_KEY_FALLBACKS", "")
SECRET_KEY_FALLBACKS: list[str] = [key.strip() for key in _fallbacks.split(",") if key.strip()]

ALLOWED_HOSTS: list[str] = env.list(
    "DJANGO_ALLOWED_HOSTS", default=["127.0.0.1", "localhost"] if DEBUG else []
)
if not DEBUG and not ALLOWED_HOSTS:
    raise ImproperlyConfigured("DJANGO_ALLOWED_HOSTS is required when DJANGO_DEBUG is off")
CSRF_TRUSTED_ORIGINS: list[str] = env.list("DJANGO_CSRF_TRUSTED_ORIGINS", default=[])

# Each robot's own agent token is stored by the portal (``manage.py agent_token``,
# bookings/agent_tokens.py). A robot without one uses a token from here, named by reference
# (``Resource.agent_token_name``): "default" is AGENT_TOKEN, the others AGENT_TOKENS'.
AGENT_TOKEN = env_secret("AGENT_TOKEN")
# Prometheus scrapes /metrics with this bearer token; without one, /metrics is off (404).
METRICS_TOKEN = env_secret("METRICS_TOKEN")
AGENT_TOKENS: dict[str, str] = {"default": AGENT_TOKEN or ""}


def _agent_tokens(value: str | None) -> dict[str, str]:
    """``name=token`` pairs, separated by commas or lines: one token per further agent."""
    tokens: dict[str, str] = {}
    for item in (value or "").replace("\n", ",").split(","):
        if not item.strip():
            continue
        name, sep, token = item.strip().partition("=")
        if not sep or not name.strip() or not token.strip():
            raise ImproperlyConfigured("AGENT_TOKENS is name=token pairs, e.g. mobile-2=…")
        tokens[name.strip()] = token.strip()
    return tokens


# Further agents' tokens by name (``Resource.agent_token_name``); "default" is AGENT_TOKEN.
AGENT_TOKENS.update(_agent_tokens(env_secret("AGENT_TOKENS")))
AGENT_URL = env.str("AGENT_URL", default="http://127.0.0.1:8700")
AGENT_TIMEOUT_S = env.float("AGENT_TIMEOUT_S", default=5.0)

# The testbed's scheduler, which owns the fixed nodes (SCHEDULER_*, docs/integration.md).
# None: no scheduler configured.
try:
    SCHEDULER: scheduler_config.SchedulerConfig | None = scheduler_config.from_env(os.environ)
except ValueError as exc:
    raise ImproperlyConfigured(str(exc)) from exc

INSTALLED_APPS = [
    # Django's admin behind allauth's sign-in, for staff whose session passed MFA.
    "core.accounts.admin_apps.StaffAdminConfig",
    "django.contrib.auth",
    "django.contrib.contenttypes",
    "django.contrib.sessions",
    "django.contrib.messages",
    "django.contrib.staticfiles",
    "rest_framework",
    # Its abstract token (hashed, with an expiry); ours is core.accounts' ApiToken.
    "knox",
    "drf_spectacular",
    # Before allauth, so that our templates override its defaults.
    "portal.web",
    "core.accounts",
    "portal.experiments",
    "portal.runs",
    "portal.queue",
    "core.audit",
    "core.events",
    "core.webhooks",
    "bookings",
    "allauth",
    "allauth.account",
    "allauth.mfa",
    "csp",
]

MIDDLEWARE = [
    "core.http.RequestIdMiddleware",
    "django.middleware.security.SecurityMiddleware",
    "csp.middleware.CSPMiddleware",
    "core.http.PermissionsPolicyMiddleware",
    "core.metrics.RequestMetricsMiddleware",
    "whitenoise.middleware.WhiteNoiseMiddleware",
    "django.contrib.sessions.middleware.SessionMiddleware",
    "django.middleware.common.CommonMiddleware",
    "django.middleware.csrf.CsrfViewMiddleware",
    "django.contrib.auth.middleware.AuthenticationMiddleware",
    "django.contrib.messages.middleware.MessageMiddleware",
    "django.middleware.clickjacking.XFrameOptionsMiddleware",
    "allauth.account.middleware.AccountMiddleware",
    # Staff powers only for a session that passed its second factor (core/accounts/staff.py).
    "core.accounts.staff.StaffSessionMiddleware",
]

ROOT_URLCONF = "portal.urls"
ASGI_APPLICATION = "portal.asgi.application"
WSGI_APPLICATION = "portal.wsgi.application"

TEMPLATES = [
    {
        "BACKEND": "django.template.backends.django.DjangoTemplates",
        "DIRS": [],
        "APP_DIRS": True,
        "OPTIONS": {
            "context_processors": [
                "django.template.context_processors.request",
                "django.contrib.auth.context_processors.auth",
                "django.contrib.messages.context_processors.messages",
                "portal.web.context_processors.testbed",
            ],
        },
    },
]

DATABASES = {
    "default": env.db("DATABASE_URL", default=f"sqlite:///{VAR_DIR / 'portal.sqlite3'}"),
}
_db_password = env_secret("DATABASE_PASSWORD")
if _db_password:
    DATABASES["default"]["PASSWORD"] = _db_password
# PostgreSQL through psycopg's connection pool (per process): a request borrows a connection
# instead of opening one (persistent connections leak one per thread under the ASGI server).
DATABASE_POOL_MAX_SIZE = env.int("DATABASE_POOL_MAX_SIZE", default=10)
if DATABASES["default"]["ENGINE"] == "django.db.backends.postgresql" and DATABASE_POOL_MAX_SIZE:
    DATABASES["default"]["CONN_MAX_AGE"] = 0  # the pool keeps the connections
    DATABASES["default"].setdefault("OPTIONS", {})["pool"] = {
        "min_size": 1,
        "max_size": DATABASE_POOL_MAX_SIZE,
        "timeout": env.float("DATABASE_POOL_TIMEOUT_S", default=10.0),
    }
if DATABASES["default"]["ENGINE"] == "django.db.backends.sqlite3":
    # Several processes (web, worker, beat) share the file: wait for locks instead of failing.
    DATABASES["default"].setdefault("OPTIONS", {}).update(
        {"timeout": 20, "transaction_mode": "IMMEDIATE", "init_command": "PRAGMA journal_mode=WAL;"}
    )
DEFAULT_AUTO_FIELD = "django.db.models.BigAutoField"

AUTH_USER_MODEL = "accounts.User"
AUTHENTICATION_BACKENDS = [
    "django.contrib.auth.backends.ModelBackend",
    "allauth.account.auth_backends.AuthenticationBackend",
]
AUTH_PASSWORD_VALIDATORS = [
    {"NAME": "django.contrib.auth.password_validation.UserAttributeSimilarityValidator"},
    {"NAME": "django.contrib.auth.password_validation.MinimumLengthValidator"},
    {"NAME": "django.contrib.auth.password_validation.CommonPasswordValidator"},
    {"NAME": "django.contrib.auth.password_validation.NumericPasswordValidator"},
]
LOGIN_URL = "account_login"
LOGIN_REDIRECT_URL = "home"
ACCOUNT_LOGOUT_REDIRECT_URL = "account_login"
ACCOUNT_LOGIN_METHODS = {"username", "email"}
ACCOUNT_SIGNUP_FIELDS = ["email*", "username*", "password1*", "password2*"]
ACCOUNT_EMAIL_VERIFICATION = env.str("ACCOUNT_EMAIL_VERIFICATION", default="optional")
ACCOUNT_ALLOW_SIGNUP = env.bool("ACCOUNT_ALLOW_SIGNUP", default=False)
ACCOUNT_ADAPTER = "core.accounts.adapter.AccountAdapter"
# Sign-in, failed sign-in, password reset (allauth's own limits besides): on in production,
# answered with 429. The API's token sign-in (``amazing login``) counts against the same.
# allauth's limits on failed sign-ins and password resets, per client address and per account.
# Always on in production; under DEBUG (a developer's machine, the test processes) only when
# SIGN_IN_LIMITS=1 asks for them, as the test that puts nginx in front does.
ACCOUNT_RATE_LIMITS: dict[str, str] | bool = (
    {"login_failed": "10/m/ip,5/5m/key", "reset_password": "20/m/ip,5/m/key"}
    if not DEBUG or env.bool("SIGN_IN_LIMITS", default=False)
    else False
)
# How many proxies of ours stand in front of the web server, each appending the address it
# saw to X-Forwarded-For (docker-compose.yml: 1, its nginx). 0: the peer's own address
# (REMOTE_ADDR) is the client's, and X-Forwarded-For is ignored. The client's address is the
# entry that many places from the right (core/http.py client_address); the entries left of
# it are the client's own word. The sign-in limits, the API throttles and the audit rows all
# take it from there.
TRUSTED_PROXY_COUNT = env.int("TRUSTED_PROXY_COUNT", default=0)
if TRUSTED_PROXY_COUNT < 0:
    raise ImproperlyConfigured(f"TRUSTED_PROXY_COUNT={TRUSTED_PROXY_COUNT}: give 0 or more")
ALLAUTH_TRUSTED_PROXY_COUNT = TRUSTED_PROXY_COUNT
# A session lasts this long from its sign-in, then the person signs in again.
SESSION_COOKIE_AGE = env.int("SESSION_AGE_S", default=12 * 3600)
# TOTP and its recovery codes. Staff must have one before any robot control, approval or
# admin page (core/accounts/mfa.py).
MFA_SUPPORTED_TYPES = ["totp", "recovery_codes"]
MFA_TOTP_ISSUER = env.str("MFA_TOTP_ISSUER", default="AMazING testbed")
# A code of the previous or next 30 s step is accepted too: a phone's clock drifts, and a
# code typed as its step ends still works.
MFA_TOTP_TOLERANCE = 1
# TOTP secrets and recovery seeds encrypted at rest; codes checked under a row lock.
MFA_ADAPTER = "core.accounts.adapter.MfaAdapter"
MFA_FORMS = {
    "authenticate": "core.accounts.mfa.LockedAuthenticateForm",
    "reauthenticate": "core.accounts.mfa.LockedReauthenticateForm",
    # A staff account's first factor only once another admin allowed it.
    "activate_totp": "core.accounts.mfa.StaffGatedActivateTOTPForm",
}
# API tokens (core/accounts/models.py ApiToken): an experimenter's has no expiry unless the
# user gives one; a staff account's always has (STAFF_API_TOKEN_DAYS).
KNOX_TOKEN_MODEL = "accounts.ApiToken"  # noqa: S105 (a model name, not a secret)
REST_KNOX = {"TOKEN_TTL": None, "TOKEN_PREFIX": "amz_"}
# Knox's own table is never made: its migrations ignore that our model replaces it.
MIGRATION_MODULES = {"knox": None}

EMAIL_BACKEND = env.str("EMAIL_BACKEND", default="django.core.mail.backends.console.EmailBackend")
DEFAULT_FROM_EMAIL = env.str("DEFAULT_FROM_EMAIL", default="AMazING testbed <noreply@localhost>")
if "EMAIL_URL" in env:
    vars().update(env.email_url("EMAIL_URL"))

LANGUAGE_CODE = "en-gb"
TIME_ZONE = env.str("TESTBED_TIME_ZONE", default="Europe/Lisbon")
USE_I18N = True
USE_TZ = True

STATIC_URL = "static/"
STATIC_ROOT = Path(env.str("STATIC_ROOT", default=str(VAR_DIR / "static")))
# Front-end packages are installed from npm at build time and copied here by the Makefile.
STATICFILES_DIRS = [Path(env.str("ASSETS_DIR", default=str(BASE_DIR / "var" / "assets")))]
STORAGES = {
    "default": {"BACKEND": "django.core.files.storage.FileSystemStorage"},
    "staticfiles": {"BACKEND": "whitenoise.storage.CompressedStaticFilesStorage"},
}
WHITENOISE_USE_FINDERS = DEBUG
WHITENOISE_AUTOREFRESH = DEBUG

REDIS_URL = env.str("REDIS_URL", default="")
# Live pushes to the pages (core/live.py) go through REDIS_URL's pub/sub; without Redis
# (make run), through files here that the web process watches.
LIVE_DIR = VAR_DIR / "live"
CACHES = {
    "default": (
        # Django's, keeping its Redis clients (core/redis_cache.py).
        {"BACKEND": "core.redis_cache.RedisCache", "LOCATION": REDIS_URL}
        if REDIS_URL
        # Files, not process memory: under `make run` the worker's notes (the scheduler's
        # heartbeat) must be visible to the web process.
        else {
            "BACKEND": "django.core.cache.backends.filebased.FileBasedCache",
            "LOCATION": str(VAR_DIR / "cache"),
        }
    )
}

# How the portal is served (portal/serve.py, portal/processes.py): pages and API on
# the WSGI server, WEB_WORKERS processes of WEB_THREADS threads (default: a process per core);
# the live streams on the ASGI server. LIVE_STREAM_PORT: where the pages open their streams
# when the ASGI server listens on its own port of the same host (make run, tests); empty
# when a proxy routes /live/ to it on the pages' own origin (docker-compose.yml).
WEB_WORKERS = env.int("WEB_WORKERS", default=os.cpu_count() or 1)
WEB_THREADS = env.int("WEB_THREADS", default=8)
LIVE_STREAM_PORT = env.int("LIVE_STREAM_PORT", default=0) or None

# Celery. The embedded default is a filesystem transport (``portal/embedded_broker.py``: kombu's,
# with atomic writes and redelivery after a consumer's death), so ``make run`` needs no broker.
CELERY_BROKER_URL = env.str("CELERY_BROKER_URL", default="filesystem://")
CELERY_BROKER_TRANSPORT_OPTIONS: dict[str, object] = {}
if CELERY_BROKER_URL.startswith(("redis://", "rediss://")):
    # kombu's, with a worker that waits out a Redis outage instead of exiting
    # (``portal/redis_broker.py``).
    CELERY_BROKER_TRANSPORT = "portal.redis_broker:Transport"
elif CELERY_BROKER_URL == "filesystem://":
    CELERY_BROKER_TRANSPORT = "portal.embedded_broker:Transport"
    _broker_dir = VAR_DIR / "broker"
    for _sub in ("queue", "inflight", "control"):
        (_broker_dir / _sub).mkdir(parents=True, exist_ok=True)
    CELERY_BROKER_TRANSPORT_OPTIONS = {
        "data_folder_in": str(_broker_dir / "queue"),
        "data_folder_out": str(_broker_dir / "queue"),
        "inflight_folder": str(_broker_dir / "inflight"),
        "bad_folder": str(_broker_dir / "bad"),
        "control_folder": str(_broker_dir / "control"),
        # An idle worker looks for new messages this often (kombu's default is 1 s): the
        # sweeps' tasks expire after two sweep intervals.
        "polling_interval": 0.2,
    }
# At least once: a task is acknowledged only when it has finished, a worker takes one at a
# time, and a task whose worker died is delivered again. Every task is safe to run twice.
CELERY_TASK_IGNORE_RESULT = True
CELERY_TASK_ACKS_LATE = True
CELERY_TASK_REJECT_ON_WORKER_LOST = True
CELERY_WORKER_PREFETCH_MULTIPLIER = 1
CELERY_TASK_TIME_LIMIT = 120
CELERY_TASK_SOFT_TIME_LIMIT = 100
CELERY_BROKER_CONNECTION_RETRY_ON_STARTUP = True
# A broker restart must never stop a worker: it reconnects for as long as it takes.
CELERY_BROKER_CONNECTION_MAX_RETRIES = None
# Redis hands an unacknowledged task to another worker after this long. Above the longest
# task plus the longest retry delay (Celery's backoff stops at 600 s), or a slow task would
# run twice at once; a task lost with a killed worker is meanwhile redone by the next sweep.
CELERY_VISIBILITY_TIMEOUT_S = 3600
CELERY_BROKER_TRANSPORT_OPTIONS["visibility_timeout"] = CELERY_VISIBILITY_TIMEOUT_S
# Two queues, each with its own worker (portal/processes.py): a backlog of mail (a slow or
# unreachable mail server) cannot delay staging and collecting a run.
CELERY_TASK_DEFAULT_QUEUE = RUNS_QUEUE
CELERY_TASK_ROUTES = {
    # The reactions to events, the e-mails among them (core/events/dispatch.py).
    "core.events.tasks.events_dispatch_all": {"queue": MAIL_QUEUE},
    # Outbound like the mail: a slow receiver never delays a run.
    "core.webhooks.tasks.webhooks_send": {"queue": MAIL_QUEUE},
}
CELERY_TIMEZONE = "UTC"
# The testbed's own timings and limits: portal/conf.py says what each means, its default and
# bounds (and writes the README's table). Read here, so that the code and the tests use them as
# any setting.
RUN_SWEEP_INTERVAL_S = conf.RUN_SWEEP_INTERVAL_S.read()
COLLECTOR_SCAN_INTERVAL_S = conf.COLLECTOR_SCAN_INTERVAL_S.read()
COLLECTOR_WAIT_S = conf.COLLECTOR_WAIT_S.read()
RUN_STAGE_LEAD_S = conf.RUN_STAGE_LEAD_S.read()
RUN_REPEAT_LEAD_S = conf.RUN_REPEAT_LEAD_S.read()
QUEUE_HORIZON_S = conf.QUEUE_HORIZON_S.read()
QUEUE_FAIR_SHARE_WINDOW_S = conf.QUEUE_FAIR_SHARE_WINDOW_S.read()
QUEUE_LEAD_S = conf.QUEUE_LEAD_S.read()
QUEUE_SLOT_S = conf.QUEUE_SLOT_S.read()
TIMELINE_SNAP_MIN = conf.TIMELINE_SNAP_MIN.read()
QUEUE_PASS_INTERVAL_S = conf.QUEUE_PASS_INTERVAL_S.read()
RUN_START_GRACE_S = conf.RUN_START_GRACE_S.read()
RUN_COLLECT_GRACE_S = conf.RUN_COLLECT_GRACE_S.read()
RESERVATION_REMINDER_LEAD_S = conf.RESERVATION_REMINDER_LEAD_S.read()
SCHEDULER_SYNC_INTERVAL_S = conf.SCHEDULER_SYNC_INTERVAL_S.read()
SCHEDULER_ORPHAN_GRACE_S = conf.SCHEDULER_ORPHAN_GRACE_S.read()
DRY_RUN_SLOTS = conf.DRY_RUN_SLOTS.read()
DRY_RUN_MAX_WAITING = conf.DRY_RUN_MAX_WAITING.read()
SELF_CHECK_LEAD_S = conf.SELF_CHECK_LEAD_S.read()
SELF_CHECK_LAP_M = conf.SELF_CHECK_LAP_M.read()
DRY_RUN_STALE_S = conf.DRY_RUN_STALE_S.read()
DRY_RUN_KEEP_S = conf.DRY_RUN_KEEP_S.read()
HEALTH_POLL_INTERVAL_S = conf.HEALTH_POLL_INTERVAL_S.read()
HEALTH_UNREACHABLE_S = conf.HEALTH_UNREACHABLE_S.read()
HEALTH_LOW_BATTERY_V = conf.HEALTH_LOW_BATTERY_V.read()
RESERVATION_MAX_S = conf.RESERVATION_MAX_S.read()
STAFF_API_TOKEN_DAYS = conf.STAFF_API_TOKEN_DAYS.read()
DOWNLOADS_IN_FLIGHT_MAX = conf.DOWNLOADS_IN_FLIGHT_MAX.read()
DOWNLOAD_SLOT_S = conf.DOWNLOAD_SLOT_S.read()
MEASUREMENT_MAX_UPLOAD_BYTES = conf.MEASUREMENT_MAX_UPLOAD_BYTES.read()
IDEMPOTENCY_KEY_TTL_S = conf.IDEMPOTENCY_KEY_TTL_S.read()
WEBHOOK_RETRY_FIRST_S = conf.WEBHOOK_RETRY_FIRST_S.read()
WEBHOOK_RETRY_MAX_S = conf.WEBHOOK_RETRY_MAX_S.read()
WEBHOOK_RETRY_FOR_S = conf.WEBHOOK_RETRY_FOR_S.read()
WEBHOOKS_PER_USER_MAX = conf.WEBHOOKS_PER_USER_MAX.read()
# Webhooks go to public https URLs only (core/webhooks/guard.py); in development also to http
# and to this machine, for a receiver of one's own.
WEBHOOK_ALLOW_HTTP = DEBUG
WEBHOOK_ALLOW_PRIVATE = DEBUG
# The shortest a beat pass waits before it expires (below: two of its intervals).
BEAT_EXPIRES_MIN_S = 2.0
CELERY_BEAT_SCHEDULE: dict[str, dict[str, Any]] = {
    "scheduler-sweep": {
        "task": "bookings.tasks.scheduler_sweep",
        "schedule": SCHEDULER_SYNC_INTERVAL_S,
    },
    "runs-sweep": {"task": "portal.runs.tasks.runs_sweep", "schedule": RUN_SWEEP_INTERVAL_S},
    "robots-health": {
        "task": "portal.runs.tasks.robots_health_sweep",
        "schedule": HEALTH_POLL_INTERVAL_S,
    },
    "reservations-remind": {"task": "bookings.tasks.reservations_remind", "schedule": 60.0},
    "queue-allocate": {
        "task": "portal.queue.tasks.queue_allocate_task",
        "schedule": QUEUE_PASS_INTERVAL_S,
    },
    # The handlers are woken after every commit that wrote events they want; this pass only
    # catches what a lost wake-up left (a process that died between its commit and the call).
    "events-dispatch": {"task": "core.events.tasks.events_dispatch_all", "schedule": 60.0},
    # The handlers whose passes the runs worker makes (the live pushes: portal/web/handlers.py).
    "events-dispatch-runs": {
        "task": "core.events.tasks.events_dispatch_all",
        "schedule": 60.0,
        "kwargs": {"queue": RUNS_QUEUE},
        "options": {"queue": RUNS_QUEUE},
    },
    # Each failed try queues the next itself; this pass catches what a dead worker left.
    "webhooks-send": {"task": "core.webhooks.tasks.webhooks_send", "schedule": 60.0},
    "dry-runs-delete-expired": {
        "task": "portal.runs.tasks.dry_runs_delete_expired",
        "schedule": 3600.0,
    },
    "self-checks-book-scheduled": {
        "task": "portal.runs.tasks.self_checks_book_scheduled",
        "schedule": 300.0,
    },
    "idempotency-keys-delete-expired": {
        "task": "core.audit.tasks.idempotency_keys_delete_expired",
        "schedule": 3600.0,
    },
}
# A pass still waiting after two of its intervals is dropped: the next one is queued behind
# it, and a worker that has fallen behind catches up on what is due now, not on a pile of
# passes that would each find it (the tasks they queue wait once each: core/pending.py).
for _entry in CELERY_BEAT_SCHEDULE.values():
    _entry.setdefault("options", {}).setdefault(
        "expires", max(2 * float(_entry["schedule"]), BEAT_EXPIRES_MIN_S)
    )
del _entry
CELERY_BEAT_SCHEDULE_FILENAME = str(VAR_DIR / "celerybeat-schedule")


def _throttle_rate(name: str, default: str) -> str | None:
    """A DRF rate such as ``50/second`` or ``1000/hour``; ``off`` turns the throttle off."""
    rate = env.str(name, default=default).strip()
    if rate.lower() in ("", "off", "none"):
        return None
    count, _, period = rate.partition("/")
    if not count.isdigit() or not period or period[0] not in "smhd":
        raise ImproperlyConfigured(f"{name}={rate!r}: give N/second, N/minute, N/hour or N/day")
    return rate


# API throttles (core/api.py): anonymous clients per address, authenticated ones per user.
API_THROTTLE_ANON = _throttle_rate("API_THROTTLE_ANON", "60/minute")
API_THROTTLE_USER = _throttle_rate("API_THROTTLE_USER", "50/second")

REST_FRAMEWORK = {
    # The token first: a request without credentials is told how to authenticate (401 with
    # WWW-Authenticate: Token). The pages' own calls use the session (with its CSRF token).
    "DEFAULT_AUTHENTICATION_CLASSES": [
        "core.accounts.tokens.CachedTokenAuthentication",
        "rest_framework.authentication.SessionAuthentication",
    ],
    "DEFAULT_PERMISSION_CLASSES": ["rest_framework.permissions.IsAuthenticated"],
    "DEFAULT_THROTTLE_CLASSES": ["core.api.AnonymousThrottle", "core.api.UserThrottle"],
    "NUM_PROXIES": TRUSTED_PROXY_COUNT,
    "DEFAULT_PARSER_CLASSES": ["rest_framework.parsers.JSONParser"],
    "DEFAULT_RENDERER_CLASSES": [
        "rest_framework.renderers.JSONRenderer",
        "rest_framework.renderers.BrowsableAPIRenderer",
    ],
    # The media type comes from Accept only, never from a ?format= that the schema would list.
    "URL_FORMAT_OVERRIDE": None,
    "DEFAULT_SCHEMA_CLASS": "core.openapi.AutoSchema",
    "DEFAULT_PAGINATION_CLASS": "core.api.Pagination",
    "EXCEPTION_HANDLER": "core.api.exception_handler",
}
SPECTACULAR_SETTINGS = {
    "TITLE": "AMazING mobile-node manager API",
    "DESCRIPTION": "",  # core.openapi.DESCRIPTION, set by its hook
    "VERSION": "1",
    "SERVE_INCLUDE_SCHEMA": False,
    "COMPONENT_SPLIT_REQUEST": True,
    # Only the token is for clients; the session cookie serves the portal's own pages.
    "AUTHENTICATION_WHITELIST": ["core.accounts.tokens.CachedTokenAuthentication"],
    "ENUM_NAME_OVERRIDES": {
        "RunStateEnum": "portal.runs.states.RunState",
        "ReservationStateEnum": "bookings.choices.ReservationState",
        "DirectionEnum": "basestation.contract.DIRECTIONS",
    },
    "POSTPROCESSING_HOOKS": [
        "drf_spectacular.hooks.postprocess_schema_enums",
        "core.openapi.postprocess_schema",
    ],
    # Swagger UI from the npm package the build installs, never from a CDN.
    "SWAGGER_UI_DIST": "/static/vendor/swagger-ui-dist",
    "SWAGGER_UI_FAVICON_HREF": "/static/vendor/swagger-ui-dist/favicon-32x32.png",
    # Without deep links each operation's path is text, not a link inside the button that
    # opens the operation (a control within a control, which screen readers cannot reach).
    "SWAGGER_UI_SETTINGS": {"deepLinking": False},
}


# What a browser may load and run on the portal's pages: its own scripts only (no inline
# script, no eval), its own styles (inline style attributes allowed: the chart and calendar
# libraries set them), no framing anywhere. The live streams may be on another port of the
# same host (make run; behind the compose proxy they share the origin).
_LIVE_ORIGINS = (
    [f"http://*:{LIVE_STREAM_PORT}", f"https://*:{LIVE_STREAM_PORT}"] if LIVE_STREAM_PORT else []
)
CONTENT_SECURITY_POLICY = {
    "DIRECTIVES": {
        "default-src": [csp_constants.SELF],
        "script-src": [csp_constants.SELF],
        "style-src": [csp_constants.SELF, csp_constants.UNSAFE_INLINE],
        "img-src": [csp_constants.SELF, "data:"],
        "font-src": [csp_constants.SELF, "data:"],
        "connect-src": [csp_constants.SELF, *_LIVE_ORIGINS],
        "object-src": [csp_constants.NONE],
        "base-uri": [csp_constants.SELF],
        "form-action": [csp_constants.SELF],
        "frame-ancestors": [csp_constants.NONE],
    }
}
SECURE_REFERRER_POLICY = "same-origin"
X_FRAME_OPTIONS = "DENY"
PERMISSIONS_POLICY_OFF = (
    "camera",
    "microphone",
    "geolocation",
    "payment",
    "usb",
    "serial",
    "bluetooth",
    "midi",
)

if not DEBUG:
    SESSION_COOKIE_SECURE = env.bool("DJANGO_SECURE_COOKIES", default=True)
    CSRF_COOKIE_SECURE = SESSION_COOKIE_SECURE
    # Behind a TLS-terminating proxy that sets X-Forwarded-Proto (deploy/nginx.conf).
    SECURE_PROXY_SSL_HEADER = ("HTTP_X_FORWARDED_PROTO", "https")
    # Plain HTTP is sent to HTTPS, but for the health check (probes call it inside the
    # deployment's network). Off only where nothing terminates TLS (compose on localhost).
    SECURE_SSL_REDIRECT = env.bool("DJANGO_SSL_REDIRECT", default=True)
    SECURE_REDIRECT_EXEMPT = [r"^healthz$"]
    # Sent on HTTPS answers only. Subdomains and preloading are the site's own decision.
    SECURE_HSTS_SECONDS = env.int("DJANGO_HSTS_SECONDS", default=365 * 24 * 3600)
    SECURE_HSTS_INCLUDE_SUBDOMAINS = env.bool("DJANGO_HSTS_INCLUDE_SUBDOMAINS", default=True)
    SECURE_HSTS_PRELOAD = env.bool("DJANGO_HSTS_PRELOAD", default=False)

# One JSON object a line in production (LOG_FORMAT=json), plain text in development; every
# line names the request id of its request or task (core/logs.py).
LOG_FORMAT = env.str("LOG_FORMAT", default="plain" if DEBUG else "json")
if LOG_FORMAT not in ("json", "plain"):
    raise ImproperlyConfigured(f"LOG_FORMAT={LOG_FORMAT!r}: give json or plain")
LOG_JSON = LOG_FORMAT == "json"
LOGGING = logging_config(json_lines=LOG_JSON, level=env.str("LOG_LEVEL", default="INFO"))
if LOG_JSON:
    # Python's warnings (a library's at start-up) as log records, so JSON lines too.
    logging.captureWarnings(True)
# A line per request from the portal itself (with its request id, view and duration); off in
# development, where the web server's own access line is printed.
ACCESS_LOG = env.bool("ACCESS_LOG", default=not DEBUG)
