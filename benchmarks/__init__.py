"""railwatch's research benchmarks: each module measures one thing and writes one page of
``docs/results/`` (or prints a table), with the command, date and CPU that made it.

Run one with ``python -m benchmarks NAME [its options]`` (or ``make bench-NAME``, hyphens for
underscores); ``python -m benchmarks`` lists them with what each needs first, its time on 2 cores
and its page. ``benchmarks/README.md`` is the index. Each module declares

- ``NEEDS``: the benchmarks whose work folder it reads (run those first, with the same
  ``--work``);
- ``PAGE``: the page it writes (None: it prints its table);
- ``MINUTES``: about how long it takes on 2 cores;

and a ``main()`` that reads its options from ``sys.argv``. What they share is in
:mod:`benchmarks.common`; they use railwatch's public API only (a test checks: no
``sys.path`` edits, no ``_private`` names).
"""
