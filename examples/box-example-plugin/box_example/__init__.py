"""An example domain plug-in for box-planning: ``slalom`` (see README.md).  Importing this
package loads neither the schema nor the domain."""
