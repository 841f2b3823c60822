"""Parameter studies on Dask: flutter maps, uncertainty (Monte Carlo) and bifurcation sweeps (issue 12).

The only package that imports dask. ``spec`` reads and validates a study file into a list of cases; ``cases``
computes one case (or one batch / one chain link) with the analysis and model layers, on a worker; ``store``
keeps the results as one xarray Dataset in Zarr, a case at a time; ``runner`` drives a Dask client (a
LocalCluster or an existing scheduler); ``plots`` draws the figures. See docs/studies.md.
"""
