"""ament_python package setup: installs the library, console scripts and share/ data."""

from glob import glob

from setuptools import find_packages, setup

package_name = "hjrno_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/experiments", glob("config/experiments/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
        ("share/" + package_name + "/rviz", glob("rviz/*.rviz")),
        ("share/" + package_name + "/models",
         [f for f in glob("models/*.json") + glob("models/*.safetensors") + glob("models/*.onnx")
          if ".train." not in f]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="hjrno_ros developers",
    maintainer_email="hjrno-ros@users.noreply.github.com",
    description="Hamilton-Jacobi reachability with neural operators as a ROS 2 safety filter",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "hjrno = hjrno_ros.cli:main",
            "brt_node = hjrno_ros.ros.brt_node.main:main",
        ],
    },
)
