"""Read files with ParaView's own readers and print what they give as JSON (run as a script).

Usage: ``python paraview_reader.py FILE...``. For an ``.xdmf`` file each of ParaView's three XDMF
readers reads every time step; a ``.pvd`` or ``.vtu`` file is read with ParaView's VTK XML
readers. Per file, reader and time: the times the reader lists, the point and cell counts, the data
type of the points and of the connectivity, and per point array its type, component count, first
tuple and whether it is the active normals; the number of datasets (a collection's parts). Run in
its own process: ParaView's libraries (HDF5 among them) stay out of the test process.
"""

import json
import sys

from paraview import servermanager, simple

XDMF_READERS = {
    "XDMFReader": lambda path: simple.XDMFReader(FileNames=[path]),
    "Xdmf3ReaderS": lambda path: simple.Xdmf3ReaderS(FileName=[path]),
    "Xdmf3ReaderT": lambda path: simple.Xdmf3ReaderT(FileName=[path]),
}
XML_READERS = {
    ".pvd": lambda path: simple.PVDReader(FileName=path),
    ".vtu": lambda path: simple.XMLUnstructuredGridReader(FileName=[path]),
}


def _leaf(data):
    """The one dataset of a reader's output (a composite output holds it as its only leaf)."""
    if data.IsA("vtkCompositeDataSet"):
        iterator = data.NewIterator()
        iterator.InitTraversal()
        return iterator.GetCurrentDataObject()
    return data


def _leaves(data) -> int:
    """How many datasets a reader's output holds (a collection's parts: one per body)."""
    if not data.IsA("vtkCompositeDataSet"):
        return 1
    iterator, count = data.NewIterator(), 0
    iterator.InitTraversal()
    while not iterator.IsDoneWithTraversal():
        count += 1
        iterator.GoToNextItem()
    return count


def _describe(data) -> dict:
    leaves = _leaves(data)
    data = _leaf(data)
    point_data = data.GetPointData()
    normals = point_data.GetNormals()
    arrays = {}
    for k in range(point_data.GetNumberOfArrays()):
        array = point_data.GetArray(k)
        arrays[array.GetName()] = {
            "type": array.GetDataTypeAsString(),
            "components": array.GetNumberOfComponents(),
            "first": list(array.GetTuple(0)),
            "normals": normals is not None and normals.GetName() == array.GetName(),
        }
    return {
        "leaves": leaves,
        "points": data.GetNumberOfPoints(),
        "cells": data.GetNumberOfCells(),
        "point_type": data.GetPoints().GetData().GetDataTypeAsString(),
        "first_point": list(data.GetPoint(0)),
        "connectivity_type": data.GetCells().GetConnectivityArray().GetDataTypeAsString(),
        "arrays": arrays,
    }


def read(path: str) -> dict:
    suffix = path[path.rfind(".") :]
    readers = XDMF_READERS if suffix == ".xdmf" else {suffix: XML_READERS[suffix]}
    result = {}
    for name, make in readers.items():
        reader = make(path)
        reader.UpdatePipelineInformation()
        times = [float(t) for t in reader.TimestepValues] if reader.TimestepValues else []
        frames = {}
        for time in times or [0.0]:
            reader.UpdatePipeline(time)
            frames[repr(time)] = _describe(servermanager.Fetch(reader))
        result[name] = {"times": times, "frames": frames}
        simple.Delete(reader)
    return result


if __name__ == "__main__":
    print(json.dumps({path: read(path) for path in sys.argv[1:]}))
