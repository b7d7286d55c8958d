"""Python package of aruco_abs_orient: used by catkin (catkin_python_setup) and by pip (the venv)."""
from setuptools import find_packages, setup

try:  # catkin reads package.xml; pip installs without ROS too
    from catkin_pkg.python_setup import generate_distutils_setup

    kwargs = generate_distutils_setup(packages=find_packages("src"), package_dir={"": "src"})
except ImportError:
    kwargs = {"name": "aruco_abs_orient", "version": "0.1.0", "packages": find_packages("src"),
              "package_dir": {"": "src"}}

setup(
    **kwargs,
    package_data={"aruco_abs_orient.detection": ["jpegrows.c"]},  # compiled on first use (detection/jpegrows.py)
    entry_points={
        "console_scripts": [
            "aruco-abs-orient = aruco_abs_orient.offline.cli:main",
            "aruco-abs-orient-synth = aruco_abs_orient.synthetic.cli:main",
            "aruco-abs-orient-ms60-sim = aruco_abs_orient.geocom.sim_cli:main",
        ],
    },
)
