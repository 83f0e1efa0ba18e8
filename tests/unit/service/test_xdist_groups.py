"""Under ``--dist loadgroup`` a test's node id carries its xdist group (``…@name``): that suffix is
how the controller keeps a group on one worker, so that its module fixtures are built once
(tests/conftest.py puts it where pytest 9 reads it; without that, every group was split)."""

import os

import pytest

pytestmark = pytest.mark.xdist_group("suffix_check")


def test_the_node_id_names_its_group(request):
    if not os.environ.get("PYTEST_XDIST_WORKER") or not request.config.getvalue("loadgroup"):
        pytest.skip("only --dist loadgroup puts the group on the node id")
    assert request.node.nodeid.endswith("@suffix_check"), request.node.nodeid
