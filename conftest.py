"""Every Python block of README.md and docs/*.md runs as a test (pytest collects them through
Sybil), each document in a fresh temporary folder, so a stale import or name cannot land. A
block that cannot run in a test (a GPU, hours) is preceded by ``<!-- skip: next "reason" -->``."""

import os
import tempfile

from sybil import Sybil
from sybil.parsers.markdown import PythonCodeBlockParser, SkipParser


def _enter_temporary_folder(namespace: dict) -> None:
    namespace["_cwd"], namespace["_tmp"] = os.getcwd(), tempfile.TemporaryDirectory()
    os.chdir(namespace["_tmp"].name)


def _leave_temporary_folder(namespace: dict) -> None:
    os.chdir(namespace["_cwd"])
    namespace["_tmp"].cleanup()


pytest_collect_file = Sybil(
    parsers=[PythonCodeBlockParser(), SkipParser()],
    patterns=["README.md", "docs/*.md"],
    setup=_enter_temporary_folder,
    teardown=_leave_temporary_folder,
).pytest()
