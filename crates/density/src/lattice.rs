//! The lattice of valid nodes: index lookup, the outer ring and the islands.

use crate::{DensityError, Island, IslandStatus, Node};
use std::collections::HashMap;

/// Node lookup by lattice index.
pub(crate) struct Lattice {
    map: HashMap<[i32; 2], usize>,
}

impl Lattice {
    pub(crate) fn new(nodes: &[Node]) -> Result<Lattice, DensityError> {
        let mut map = HashMap::with_capacity(nodes.len());
        for (p, n) in nodes.iter().enumerate() {
            if map.insert(n.index, p).is_some() {
                return Err(DensityError::DuplicateIndex(n.index));
            }
        }
        Ok(Lattice { map })
    }

    /// The node at `index`, if valid.
    pub(crate) fn get(&self, index: [i32; 2]) -> Option<usize> {
        self.map.get(&index).copied()
    }
}

/// Whether each node lies on the outer ring of the lattice: a node with a 4-neighbour site
/// that is not a node and is reachable from outside the lattice's bounding box through such
/// sites. Sites enclosed by nodes (holes: invalid or masked dots inside the field) do not make
/// a ring node; their edges are Neumann boundaries.
///
/// ```
/// use bostrack_density::outer_ring;
/// // a 5 × 5 block with a hole in the middle: 16 ring nodes, the hole's neighbours are not
/// let idx: Vec<[i32; 2]> = (0..5).flat_map(|i| (0..5).map(move |j| [i, j]))
///     .filter(|&ij| ij != [2, 2]).collect();
/// let ring = outer_ring(&idx);
/// assert_eq!(ring.iter().filter(|r| **r).count(), 16);
/// assert!(!ring[idx.iter().position(|&ij| ij == [1, 2]).unwrap()]);
/// ```
pub fn outer_ring(indices: &[[i32; 2]]) -> Vec<bool> {
    if indices.is_empty() {
        return Vec::new();
    }
    let (mut i0, mut i1, mut j0, mut j1) = (i32::MAX, i32::MIN, i32::MAX, i32::MIN);
    for &[i, j] in indices {
        i0 = i0.min(i);
        i1 = i1.max(i);
        j0 = j0.min(j);
        j1 = j1.max(j);
    }
    // the bounding box with a margin of one site; lattice indices are dense (at most one site
    // per dot of the image), so the box is of the order of the number of nodes
    let rows = (i1 as i64 - i0 as i64 + 3) as usize;
    let cols = (j1 as i64 - j0 as i64 + 3) as usize;
    let at = |i: i32, j: i32| (i - i0 + 1) as usize * cols + (j - j0 + 1) as usize;
    let mut occupied = vec![false; rows * cols];
    for &[i, j] in indices {
        occupied[at(i, j)] = true;
    }
    // flood fill of the free sites from the margin
    let mut outside = vec![false; rows * cols];
    let mut stack = vec![0usize];
    outside[0] = true;
    while let Some(s) = stack.pop() {
        let (r, c) = (s / cols, s % cols);
        let mut visit = |t: usize| {
            if !occupied[t] && !outside[t] {
                outside[t] = true;
                stack.push(t);
            }
        };
        if r > 0 {
            visit(s - cols);
        }
        if r + 1 < rows {
            visit(s + cols);
        }
        if c > 0 {
            visit(s - 1);
        }
        if c + 1 < cols {
            visit(s + 1);
        }
    }
    indices
        .iter()
        .map(|&[i, j]| {
            let s = at(i, j);
            outside[s - cols] || outside[s + cols] || outside[s - 1] || outside[s + 1]
        })
        .collect()
}

/// The islands and which island each node is on.
pub(crate) struct Islands {
    pub of_node: Vec<usize>,
    pub islands: Vec<Island>,
}

/// Connected parts of the graph whose edges are `links` (pairs of nodes that share an
/// observation); numbered in order of their first node.
pub(crate) fn islands(n: usize, links: &[(usize, usize)], nodes: &[Node]) -> Islands {
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    for &(a, b) in links {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra.max(rb)] = ra.min(rb);
        }
    }
    let mut number = vec![usize::MAX; n];
    let mut of_node = vec![0; n];
    let mut islands: Vec<Island> = Vec::new();
    for p in 0..n {
        let r = find(&mut parent, p);
        if number[r] == usize::MAX {
            number[r] = islands.len();
            islands.push(Island {
                nodes: 0,
                reference_nodes: 0,
                status: IslandStatus::NoReference,
            });
        }
        let k = number[r];
        of_node[p] = k;
        islands[k].nodes += 1;
        if nodes[p].dirichlet {
            islands[k].reference_nodes += 1;
            islands[k].status = IslandStatus::Solved;
        }
    }
    Islands { of_node, islands }
}
