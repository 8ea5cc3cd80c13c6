"""Pure algorithms, the model and the field's file formats (numpy/torch only).

Never imports prefect, zarr or pyarrow.
"""

__version__ = "0.1.0"
