"""The service's configuration: the store's settings plus what only the service reads.

``ServiceSettings`` extends the job store's :class:`jobs.record.config.Settings`
(data folder, database, work and disk limits) with the HTTP front's access and
limits and the TLS of scale-out scheduler connections, in the style of the FastAPI
full-stack template's ``core/config.py``. Every field is read from the same
environment variables as before, with the prefix ``NIRC_BENCH_``
(``NIRC_BENCH_PUBLIC_READ``, ``NIRC_BENCH_LONG_POLL_MAX_S``,
``NIRC_BENCH_MAX_BODY_BYTES``, ``NIRC_BENCH_TLS_CA_FILE``, ...); docs/security.md and
docs/service.md say what each one does.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

from pydantic import Field, field_validator
from pydantic_settings import NoDecode

from jobs.record.config import Settings

if TYPE_CHECKING:
    from jobs.execution.dispatch import SchedulerTLS


class ServiceSettings(Settings):
    """The store's settings and the service's own (``nirc-bench serve``, ``worker``)."""

    # ---- HTTP: access and limits (docs/security.md) ----
    # Whether GETs (results, jobs with their specs and errors, worker addresses) are
    # open to anyone who can reach the service. None: on if `serve` binds to
    # loopback; on any other address `serve` refuses to start until it is chosen.
    public_read: bool | None = None
    # The host names the service answers to (the request's Host header; any other is
    # answered 400), so that a web page cannot reach it through a domain of its own
    # that resolves to this machine (DNS rebinding). Comma-separated in the
    # environment; "*" accepts any. None: `serve` answers to loopback names and the
    # address it binds to (LOOPBACK_HOSTS + --host), and refuses a wildcard bind
    # (0.0.0.0, ::) until they are chosen.
    allowed_hosts: Annotated[list[str] | None, NoDecode] = None
    # How long a dashboard login lasts (its server-side session; the cookie holds only
    # the session's token).
    session_max_age_s: float = Field(12 * 3600.0, gt=0.0)
    # The largest request body accepted (413 beyond, counted as it streams in).
    max_body_bytes: int = Field(1_000_000, ge=1024)
    # The longest a long poll (GET /api/v1/jobs/{id}?wait_s=) holds a request open,
    # below the idle timeouts of proxies in front of the service.
    long_poll_max_s: float = Field(30.0, ge=0.0)
    # Long polls waiting at once; more are answered 429 (each costs a database read
    # per poll interval, not a thread).
    long_poll_max_waiters: int = Field(256, ge=1)
    # Scene uploads vetted at once: each holds its XML (up to the scenes' file size
    # limit) and its parsed tree in memory; more are answered 503 with Retry-After.
    max_scene_parses: int = Field(2, ge=1)
    # ---- HTTP: clients that send slowly (docs/security.md, service/slow_clients.py) ----
    # Seconds a connection may take to send a request's headers, counted from its
    # opening or from the end of its previous response; it is cut after (408).
    header_timeout_s: float = Field(10.0, gt=0.0)
    # A request body must bring at least body_min_bytes_per_s on average over each
    # window of body_window_s while the service waits for it; it is cut otherwise.
    body_window_s: float = Field(10.0, gt=0.0)
    body_min_bytes_per_s: float = Field(1000.0, ge=0.0)
    # Connections open at once: a request on any connection while more are open is
    # answered 503 and its connection closed (each costs a socket, a file descriptor
    # and buffers; keep it well under the process's open-file limit, `ulimit -n`).
    max_connections: int = Field(512, ge=1)
    # ---- Scale-out: the Dask scheduler connection (docs/security.md) ----
    # TLS of the scale-out Dask connections (tls:// scheduler addresses): the CA that
    # signed the scheduler's and workers' certificates, and this process's own
    # certificate and private key (PEM files).
    tls_ca_file: Path | None = None
    tls_cert: Path | None = None
    tls_key: Path | None = None
    # A tcp:// scheduler off loopback (no encryption, no authentication: whoever reaches
    # it runs code on the workers) is refused unless this is on.
    allow_plaintext_scheduler: bool = False
    # The embedded cluster's Dask dashboards (scheduler and workers, on loopback ports,
    # unauthenticated): off unless asked for (`serve --dask-dashboard`).
    dask_dashboard: bool = False

    @field_validator("allowed_hosts", mode="before")
    @classmethod
    def _comma_separated(cls, value: object) -> object:
        if isinstance(value, str):
            return [name.strip() for name in value.split(",") if name.strip()]
        return value

    @classmethod
    def of(cls, settings: Settings) -> ServiceSettings:
        """``settings`` as the service's: a store's settings keep their values and get
        the service's own from the environment (or their defaults)."""
        if isinstance(settings, cls):
            return settings
        return cls(**settings.model_dump())

    @property
    def scheduler_tls(self) -> SchedulerTLS | None:
        """The TLS files of scheduler connections, None when none is configured."""
        from jobs.execution.dispatch import SchedulerTLS

        if self.tls_ca_file is None:
            return None
        return SchedulerTLS(ca_file=self.tls_ca_file, cert=self.tls_cert, key=self.tls_key)


#: The names of this machine on loopback, which the service answers to by default.
LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1")


def host_patterns(names: list[str]) -> list[str]:
    """``names`` as the Host header spells them: an IPv6 address in brackets
    (``::1`` -> ``[::1]``), everything lower-case."""
    patterns = []
    for name in names:
        bare = name.strip("[]").lower()
        try:
            bracketed = ipaddress.ip_address(bare).version == 6
        except ValueError:
            bracketed = False
        patterns.append(f"[{bare}]" if bracketed else bare)
    return patterns
