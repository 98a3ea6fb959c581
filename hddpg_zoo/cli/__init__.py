"""
The harness's ``hddpg-cli`` commands (benchmark, report, tune, quickstart, record, package...): each module
registers its command on the library's application (:mod:`sb3_hddpg.cli.app`), which imports it lazily
through its ``COMMANDS`` table.
"""
