"""
``mlx-tempcomp fleet``: the single-record commands over every unit of a fleet, on Dask.

`manifest` says which records belong to which unit, `unit` runs one unit's
records through the same code as ``mlx-tempcomp diagnose``/``fit`` (on a Dask
worker, no Dask in it), `run` schedules the units on a Dask cluster and keeps
what finished, `connection` connects it to a scheduler (over TLS with the
client's certificates; a refusal in one line), `report` compares the units,
`command` is the command line.
Only `run` imports Dask, inside its functions, so ``mlx-tempcomp --help``
loads none of it. docs/fleet.md describes the commands.
"""
