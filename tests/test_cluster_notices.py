"""Ray's token notice never reaches stderr above a one-line error (issue 45), and fd 2 is left alone."""

from __future__ import annotations

import logging

from vprsnn_export.cluster import RAY_NOTICE_LOGGER, keep_ray_notices_back


def test_the_token_notice_is_dropped_and_other_ray_warnings_kept(caplog):
    keep_ray_notices_back()
    keep_ray_notices_back()  # once: no second filter
    notices = logging.getLogger(RAY_NOTICE_LOGGER)
    assert len(notices.filters) == 1
    with caplog.at_level(logging.WARNING):
        notices.warning("Token authentication is enabled for this Ray cluster. Set RAY_AUTH_MODE=disabled ...")
        notices.warning("Token authentication is enabled but no token was found.")
    assert [r.getMessage() for r in caplog.records] == ["Token authentication is enabled but no token was found."]
