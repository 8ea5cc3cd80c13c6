"""A remote store's first contact: can its endpoint be reached, with these credentials?

botocore retries a refused connection with back-off (10-40 s before the error surfaces, with a
traceback), and a missing credential or a wrong key surfaces as a bare ``NoCredentialsError`` or
``PermissionError: Forbidden``. :func:`check_s3` asks once, with short timeouts and no retries,
and says in one line what is wrong and what to check. A store that answered is not asked again in
this process.
"""

from __future__ import annotations

import json
import os
import posixpath
import time
from typing import Any

from storage.errors import StoreAccessError

CONNECT_TIMEOUT_S = 3.0
READ_TIMEOUT_S = 10.0
BUSY_RETRIES_S = (0.2, 0.5, 1.0, 2.0)
"""Waits before asking again when the endpoint answers that it is busy (503 SlowDown, 500): an
answer that comes back, unlike a refused connection or key, which is final at once."""
BUSY = ("SlowDown", "reduce your request rate", "ServiceUnavailable", "InternalError", "503", "500")
_ENV = ("AWS_ENDPOINT_URL", "AWS_ENDPOINT_URL_S3", "AWS_ACCESS_KEY_ID", "AWS_PROFILE")
_ANSWERED: set[str] = set()


def endpoint_of(storage_options: dict[str, Any]) -> str:
    """The S3 endpoint the options (or the environment) point at, for messages."""
    client = storage_options.get("client_kwargs") or {}
    return (
        storage_options.get("endpoint_url")
        or client.get("endpoint_url")
        or os.environ.get("AWS_ENDPOINT_URL_S3")
        or os.environ.get("AWS_ENDPOINT_URL")
        or "AWS's default endpoint"
    )


def check_s3(uri: str, path: str, storage_options: dict[str, Any]) -> None:
    """List at most one key under ``path`` (``bucket/prefix``) with short timeouts and no retries.

    Args:
        uri: the store's URL (``s3://bucket/prefix``), for messages.
        path: ``bucket/prefix`` as s3fs names it.
        storage_options: the store's fsspec options (endpoint, key, secret, client settings).

    Raises:
        StoreAccessError: the endpoint cannot be reached, no credentials were found, the key is
            refused, or the bucket does not exist; the message names the URL, the endpoint and
            what to check.
    """
    key = json.dumps([path.split("/", 1)[0], storage_options, [os.environ.get(v) for v in _ENV]], default=str)
    if key in _ANSWERED:
        return
    import s3fs
    from botocore.exceptions import ConnectionError as BotoConnectionError
    from botocore.exceptions import HTTPClientError, NoCredentialsError, PartialCredentialsError

    opts = dict(storage_options)
    config = dict(opts.pop("config_kwargs", None) or {})
    config.setdefault("connect_timeout", CONNECT_TIMEOUT_S)
    config.setdefault("read_timeout", READ_TIMEOUT_S)
    config["retries"] = {"max_attempts": 1, "mode": "standard"}
    opts.pop("use_listings_cache", None)
    fs = s3fs.S3FileSystem(**opts, config_kwargs=config, skip_instance_cache=True)
    fs.retries = 1  # s3fs's own retry loop (botocore's is off through config_kwargs)
    bucket, _, prefix = path.partition("/")
    endpoint = endpoint_of(storage_options)
    try:
        _list_one(fs, bucket, prefix)
    except (NoCredentialsError, PartialCredentialsError) as exc:
        raise StoreAccessError(
            uri,
            f"no S3 credentials ({exc}): set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (or AWS_PROFILE, "
            "or the key and secret storage options)",
        ) from None
    except (BotoConnectionError, HTTPClientError) as exc:  # refused, timed out, DNS, TLS: no answer
        raise StoreAccessError(
            uri,
            f"cannot reach the S3 endpoint {endpoint} ({type(exc).__name__}); check AWS_ENDPOINT_URL (or the "
            "endpoint_url storage option) and that the service is up",
        ) from None
    except PermissionError as exc:
        raise StoreAccessError(
            uri,
            f"the S3 endpoint {endpoint} refused access ({exc}); check AWS_ACCESS_KEY_ID and "
            "AWS_SECRET_ACCESS_KEY and the bucket's permissions",
        ) from None
    except FileNotFoundError:
        raise StoreAccessError(
            uri, f"bucket {bucket!r} does not exist at {endpoint}; create it or check the URL"
        ) from None
    except OSError as exc:
        raise StoreAccessError(uri, f"the S3 endpoint {endpoint} answered: {exc}") from None
    _ANSWERED.add(key)


def _list_one(fs, bucket: str, prefix: str) -> None:
    """One listing of at most one key, asked again (:data:`BUSY_RETRIES_S`) while the endpoint says
    it is busy."""
    for wait in (*BUSY_RETRIES_S, None):
        try:
            fs.call_s3("list_objects_v2", Bucket=bucket, Prefix=posixpath.join(prefix, ""), MaxKeys=1)
            return
        except OSError as exc:
            if wait is None or isinstance(exc, PermissionError | FileNotFoundError):
                raise
            if not any(word in str(exc) for word in BUSY):
                raise
            time.sleep(wait)
